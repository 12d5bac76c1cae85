//! A pty pair for the twin: the twin keeps the master end (non-blocking,
//! driven by tokio's `AsyncFd`); the slave end's path is what a
//! workstation opens as its serial port. The slave is set raw and kept open
//! so the line survives the workstation closing and reopening it.

use nix::fcntl::{fcntl, FcntlArg, OFlag};
use nix::pty::openpty;
use nix::sys::termios::{cfmakeraw, tcgetattr, tcsetattr, SetArg};
use std::io;
use std::os::fd::{AsFd, AsRawFd, OwnedFd};
use tokio::io::unix::AsyncFd;

/// The master end of a pty pair, and the slave's path.
pub struct Pty {
    master: AsyncFd<OwnedFd>,
    _slave: OwnedFd,
    /// The slave's path (`/dev/pts/N`).
    pub path: String,
}

impl Pty {
    /// Opens a raw pty pair.
    pub fn open() -> io::Result<Pty> {
        let pair = openpty(None, None).map_err(io::Error::from)?;
        let mut t = tcgetattr(pair.slave.as_fd()).map_err(io::Error::from)?;
        cfmakeraw(&mut t);
        tcsetattr(pair.slave.as_fd(), SetArg::TCSANOW, &t).map_err(io::Error::from)?;
        let path = nix::unistd::ttyname(pair.slave.as_fd())
            .map_err(io::Error::from)?
            .display()
            .to_string();
        let flags = fcntl(pair.master.as_raw_fd(), FcntlArg::F_GETFL).map_err(io::Error::from)?;
        fcntl(
            pair.master.as_raw_fd(),
            FcntlArg::F_SETFL(OFlag::from_bits_truncate(flags) | OFlag::O_NONBLOCK),
        )
        .map_err(io::Error::from)?;
        // SAFETY: the OwnedFd owns the master descriptor for as long as the
        // AsyncFd holds it, and always returns that same descriptor.
        let master = unsafe { AsyncFd::register(pair.master) }?;
        Ok(Pty {
            master,
            _slave: pair.slave,
            path,
        })
    }

    /// Reads what the workstation wrote.
    pub async fn read(&self, buf: &mut [u8]) -> io::Result<usize> {
        loop {
            let mut guard = self.master.readable().await?;
            match guard.try_io(|fd| nix::unistd::read(fd.as_raw_fd(), buf).map_err(io::Error::from))
            {
                Ok(r) => return r,
                Err(_would_block) => continue,
            }
        }
    }

    /// Writes to the workstation.
    pub async fn write_all(&self, mut data: &[u8]) -> io::Result<()> {
        while !data.is_empty() {
            let mut guard = self.master.writable().await?;
            match guard.try_io(|fd| nix::unistd::write(fd.get_ref(), data).map_err(io::Error::from))
            {
                Ok(Ok(n)) => data = &data[n..],
                Ok(Err(e)) => return Err(e),
                Err(_would_block) => continue,
            }
        }
        Ok(())
    }
}
