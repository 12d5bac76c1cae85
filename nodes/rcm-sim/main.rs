//! `falc-rcm-sim`: the digital twin of the RCM 815 robot controller. It
//! speaks DNC over 3964R (with the RCM's priority) on a pty pair (default;
//! it prints the port to connect to) or a given serial device (`--device`) and keeps the real controller's modes
//! and program table, scaled by `--time-scale`. Optional wire timing
//! (`--wire-baud`) makes every byte take as long as on a real line.
//!
//! On stdout: the port line, then `rx <telegram>` for each telegram
//! received from the host (`rx S065`, `rx G`, `rx H`).
//!
//! Control lines on stdin (answered `ok …` or `error …` on stdout):
//! `estop`, `estop-clear`, `person-in`, `person-out`, `limit-switch`,
//! `abort-weld`, `alarm <code>`, `mode manual|automatic|aue`, `noise <n>`
//! (n random bytes on the line), `flips <percent>` (from now on each byte
//! on the line, either way, has one bit flipped with that chance; `flips
//! 0` ends it; answered with the count of bytes flipped so far),
//! `unplug`, `replug`, `lose-end` (the next program end is never sent:
//! the host must learn it from the status), `lose-ack` (the next
//! acknowledgement of a select or start is never sent: likewise).

use anyhow::{Context, Result};
use clap::Parser;
use falc_dnc::procedure::Timing;
use falc_dnc::robot::{Control, Robot};
use falc_dnc::telegram::Mode;
use falc_dnc::twin::{Note, RcmTwin};
use falc_node::say;
use std::time::Duration;
use tokio::io::{AsyncBufReadExt, AsyncReadExt, AsyncWriteExt, BufReader};
use tokio::time::Instant;
use tokio_serial::{SerialPort, SerialStream};

#[derive(Parser, Debug)]
#[command(
    version,
    about = "Digital twin of the RCM 815 robot controller (DNC over 3964R on a pty)"
)]
struct Cli {
    /// Program durations are divided by this (10 = ten times faster).
    #[arg(long, default_value_t = 1.0)]
    time_scale: f64,
    /// Emulate the wire time of each byte at this baud rate (0 = off).
    #[arg(long, default_value_t = 0)]
    wire_baud: u32,
    /// The mode at start: manual, automatic or aue (automatic-external, DNC).
    #[arg(long, default_value = "aue")]
    mode: String,
    /// A serial device to use instead of a new pty pair, and its settings.
    #[command(flatten)]
    line: falc_node::dnc_link::LineArgs,
}

/// Opens a raw pty pair (tokio-serial's): the twin's end, the end a
/// workstation opens (kept open here, so the line survives the workstation
/// closing and reopening it), and that end's path (`/dev/pts/N`).
fn pty_pair() -> Result<(SerialStream, SerialStream, String)> {
    let (twin, workstation) = SerialStream::pair().context("cannot open a pty pair")?;
    let path = workstation.name().context("the new pty has no path")?;
    Ok((twin, workstation, path))
}

fn parse_mode(s: &str) -> Option<Mode> {
    match s {
        "manual" => Some(Mode::Manual),
        "automatic" => Some(Mode::Automatic),
        "aue" => Some(Mode::AutomaticExternal),
        _ => None,
    }
}

enum Line {
    Control(Control),
    Noise(usize),
    Flips(f64),
    Unplug,
    Replug,
    Programs,
}

fn parse_control(line: &str) -> Result<Line, String> {
    let words: Vec<&str> = line.split_whitespace().collect();
    Ok(match words.as_slice() {
        ["estop"] => Line::Control(Control::EStop),
        ["estop-clear"] => Line::Control(Control::EStopClear),
        ["person-in"] => Line::Control(Control::PersonIn),
        ["person-out"] => Line::Control(Control::PersonOut),
        ["limit-switch"] => Line::Control(Control::LimitSwitch),
        ["abort-weld"] => Line::Control(Control::AbortWeld),
        ["lose-end"] => Line::Control(Control::LoseEnd),
        ["lose-ack"] => Line::Control(Control::LoseAck),
        ["alarm", code] => Line::Control(Control::Alarm(
            code.parse()
                .map_err(|_| format!("bad alarm code `{code}`"))?,
        )),
        ["mode", m] => Line::Control(Control::Mode(
            parse_mode(m).ok_or(format!("unknown mode `{m}`"))?,
        )),
        ["noise", n] => Line::Noise(n.parse().map_err(|_| format!("bad count `{n}`"))?),
        ["flips", p] => Line::Flips(
            p.parse::<f64>()
                .ok()
                .filter(|p| (0.0..=100.0).contains(p))
                .ok_or(format!("bad percentage `{p}` (0 to 100)"))?,
        ),
        ["unplug"] => Line::Unplug,
        ["replug"] => Line::Replug,
        ["programs"] => Line::Programs,
        _ => return Err(format!("unknown control `{line}`")),
    })
}

#[tokio::main(flavor = "current_thread")]
async fn main() -> Result<()> {
    falc_node::init_tracing();
    let cli = Cli::parse();
    let mode = parse_mode(&cli.mode)
        .with_context(|| format!("unknown mode `{}` (manual, automatic, aue)", cli.mode))?;
    let (mut port, _workstation_end, path) = match cli.line.settings(None) {
        Some(line) => {
            let serial = falc_node::dnc_link::open_serial(&line).map_err(anyhow::Error::msg)?;
            (serial, None, line.path)
        }
        None => {
            let (twin, workstation, path) = pty_pair()?;
            (twin, Some(workstation), path)
        }
    };
    let mut twin = RcmTwin::new(Robot::new(mode, cli.time_scale), Timing::default());
    let byte_time = if cli.wire_baud > 0 {
        Duration::from_secs_f64(10.0 / f64::from(cli.wire_baud))
    } else {
        Duration::ZERO
    };
    say(&format!("falc-rcm-sim serial port: {path}"));
    let origin = Instant::now();
    let now = || Instant::now().duration_since(origin);
    let mut stdin = BufReader::new(tokio::io::stdin()).lines();
    let mut stdin_open = true;
    let mut plugged = true;
    // The chance of a bit flip per byte on the line (`flips`).
    let mut flips = 0.0_f64;
    let mut flipped_bytes = 0u64;
    let mut buf = [0u8; 256];
    loop {
        while let Some(note) = twin.poll_note() {
            match note {
                // One line per telegram received, for tests and people.
                Note::Received(t) => say(&format!("rx {}", String::from_utf8_lossy(&t.encode()))),
                Note::Trouble(why) => tracing::warn!("{why}"),
                Note::Robot(what) => say(&what),
            }
        }
        if let Some(bytes) = twin.poll_transmit() {
            if plugged {
                wire_delay(byte_time * bytes.len() as u32);
                let bytes = flipped(bytes, flips, &mut flipped_bytes);
                tracing::debug!(bytes = %bytes.escape_ascii(), "to the line");
                port.write_all(&bytes).await.context("pty write")?;
            }
        }
        let deadline = twin
            .poll_timeout()
            .map_or(Instant::now() + Duration::from_secs(3600), |t| origin + t);
        tokio::select! {
            n = port.read(&mut buf) => {
                let n = n.context("pty read")?;
                tracing::debug!(bytes = %buf[..n].escape_ascii(), plugged, "from the line");
                if plugged && n > 0 {
                    wire_delay(byte_time * n as u32);
                    twin.handle_bytes(now(), &flipped(buf[..n].to_vec(), flips, &mut flipped_bytes));
                }
            }
            line = stdin.next_line(), if stdin_open => match line {
                Ok(Some(line)) if line.trim().is_empty() => {}
                Ok(Some(line)) => match parse_control(line.trim()) {
                    Ok(Line::Control(c)) => {
                        twin.control(now(), c);
                        say(&format!("ok {}", line.trim()));
                    }
                    Ok(Line::Noise(n)) => {
                        let noise: Vec<u8> = (0..n).map(|_| rand_byte()).collect();
                        port.write_all(&noise).await.context("pty write")?;
                        say(&format!("ok {}", line.trim()));
                    }
                    Ok(Line::Flips(p)) => {
                        flips = p / 100.0;
                        say(&format!("ok {} ({flipped_bytes} bytes flipped so far)", line.trim()));
                    }
                    Ok(Line::Unplug) => {
                        plugged = false;
                        say("ok unplug");
                    }
                    Ok(Line::Replug) => {
                        plugged = true;
                        say("ok replug");
                    }
                    Ok(Line::Programs) => {
                        let stored: Vec<String> = twin
                            .robot
                            .delivered()
                            .map(|(p, lines, hash)| format!("{} ({lines} lines, hash {hash:08X})", p.number()))
                            .collect();
                        say(&format!("programs delivered: {}", if stored.is_empty() { "none".to_string() } else { stored.join(", ") }));
                        say("ok programs");
                    }
                    Err(e) => say(&format!("error {e}")),
                },
                Ok(None) | Err(_) => stdin_open = false,
            },
            _ = tokio::time::sleep_until(deadline) => twin.handle_timeout(now()),
        }
    }
}

/// The time bytes take on the emulated line. A precise thread sleep, not a
/// tokio timer (1 ms granularity would add up to a millisecond to every
/// one-byte DLE); the line is busy meanwhile, so blocking is faithful.
fn wire_delay(d: Duration) {
    if !d.is_zero() {
        std::thread::sleep(d);
    }
}

/// `bytes` as a noisy line delivers them: each with one random bit
/// flipped with chance `p` (counted in `count`).
fn flipped(mut bytes: Vec<u8>, p: f64, count: &mut u64) -> Vec<u8> {
    if p > 0.0 {
        for b in &mut bytes {
            if rand::random::<f64>() < p {
                *b ^= 1 << (rand::random::<u8>() % 8);
                *count += 1;
            }
        }
    }
    bytes
}

fn rand_byte() -> u8 {
    rand::random()
}
