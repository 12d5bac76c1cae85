//! The DNC driver: runs the 3964R [`Link`] over any byte stream (a
//! tokio-serial port, a pty) with the real clock. Telegrams go in over a
//! channel; link events come out over another. The driver only moves bytes
//! and time; every rule lives in [`falc_dnc::procedure`].

use falc_dnc::procedure::{Link, LinkEvent};
use std::time::Duration;
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::sync::mpsc::{unbounded_channel, UnboundedReceiver, UnboundedSender};
use tokio::time::Instant;

/// Serial line settings.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LineSettings {
    /// The device (`/dev/ttyS0`, a pty's `/dev/pts/N`).
    pub path: String,
    /// Baud rate.
    pub baud: u32,
    /// Parity: `none`, `even` or `odd`.
    pub parity: String,
}

/// The serial-line arguments of every node on a DNC line (workstation and
/// twin alike).
#[derive(Debug, Clone, clap::Args)]
pub struct LineArgs {
    /// The serial device (a real port, or a pty's `/dev/pts/N`).
    #[arg(long)]
    pub device: Option<String>,
    /// Baud rate.
    #[arg(long, default_value_t = 9600)]
    pub baud: u32,
    /// Parity: none, even, odd.
    #[arg(long, default_value = "none")]
    pub parity: String,
}

impl LineArgs {
    /// The line settings, with `fallback` as the device when none is given.
    pub fn settings(&self, fallback: Option<String>) -> Option<LineSettings> {
        self.device.clone().or(fallback).map(|path| LineSettings {
            path,
            baud: self.baud,
            parity: self.parity.clone(),
        })
    }
}

/// Opens a serial device (or a pty's slave end) with 8 data bits, 1 stop
/// bit, no flow control, and `settings`' baud rate and parity.
pub fn open_serial(settings: &LineSettings) -> Result<tokio_serial::SerialStream, String> {
    use tokio_serial::{DataBits, FlowControl, Parity, SerialPortBuilderExt, StopBits};
    let parity = match settings.parity.as_str() {
        "none" => Parity::None,
        "even" => Parity::Even,
        "odd" => Parity::Odd,
        other => return Err(format!("unknown parity `{other}` (none, even, odd)")),
    };
    tokio_serial::new(&settings.path, settings.baud)
        .data_bits(DataBits::Eight)
        .stop_bits(StopBits::One)
        .parity(parity)
        .flow_control(FlowControl::None)
        .open_native_async()
        .map_err(|e| format!("no connection with RCM on {}: {e}", settings.path))
}

/// The two ends of a running driver.
pub struct DncHandle {
    /// Telegrams to send.
    pub send: UnboundedSender<Vec<u8>>,
    /// What the link reports; None when the line is gone.
    pub events: UnboundedReceiver<LinkEvent>,
}

/// Spawns a driver of `link` over `port`.
pub fn spawn<P>(port: P, link: Link) -> DncHandle
where
    P: AsyncRead + AsyncWrite + Unpin + Send + 'static,
{
    let (send_tx, send_rx) = unbounded_channel();
    let (ev_tx, ev_rx) = unbounded_channel();
    tokio::spawn(run(port, link, send_rx, ev_tx));
    DncHandle {
        send: send_tx,
        events: ev_rx,
    }
}

async fn run<P>(
    mut port: P,
    mut link: Link,
    mut telegrams: UnboundedReceiver<Vec<u8>>,
    events: UnboundedSender<LinkEvent>,
) where
    P: AsyncRead + AsyncWrite + Unpin,
{
    let origin = Instant::now();
    let now = || Instant::now().duration_since(origin);
    let mut buf = [0u8; 256];
    loop {
        if let Some(bytes) = link.poll_transmit() {
            tracing::trace!(bytes = %bytes.escape_ascii(), "to the line");
            if let Err(e) = port.write_all(&bytes).await {
                tracing::warn!("DNC line write failed: {e}");
                return;
            }
        }
        while let Some(ev) = link.poll_event() {
            if events.send(ev).is_err() {
                return; // nobody listens any more
            }
        }
        let sleep = match link.poll_timeout() {
            Some(t) => origin + t,
            None => Instant::now() + Duration::from_secs(3600),
        };
        tokio::select! {
            t = telegrams.recv() => match t {
                Some(t) => link.send(now(), t),
                None => return,
            },
            n = port.read(&mut buf) => match n {
                Ok(0) | Err(_) => {
                    tracing::warn!("DNC line closed");
                    return;
                }
                Ok(n) => {
                    tracing::trace!(bytes = %buf[..n].escape_ascii(), "from the line");
                    link.handle_bytes(now(), &buf[..n])
                }
            },
            _ = tokio::time::sleep_until(sleep) => link.handle_timeout(now()),
        }
    }
}
