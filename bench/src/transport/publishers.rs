//! The publishing processes: this program again, started and driven by the bench
//! ([`Publishers`]), and what each of them does ([`publish`]).

use std::io::{BufRead, BufReader, Write};
use std::os::unix::net::UnixStream;
use std::process::{Child, ChildStdout, Command, Stdio};
use std::time::Duration;

use anyhow::{Context, Result, ensure};
use wire::{ShmTransport, Topic, Transport};

use super::args::{TransportBenchArgs, Via, limits};
use super::cpus::pin_to;
use super::message::{message_of, nanos_now};

/// The publishing processes of one measurement; killed if still running when dropped.
pub(super) struct Publishers {
    children: Vec<(Child, BufReader<ChildStdout>)>,
}

impl Publishers {
    pub(super) fn start(
        via: Via,
        to: &str,
        count: usize,
        messages: usize,
        size: usize,
        cpu: Option<usize>,
    ) -> Result<Self> {
        let exe = std::env::current_exe().context("finding this program")?;
        let mut publishers = Self {
            children: Vec::new(),
        };
        for index in 0..count {
            let mut command = Command::new(&exe);
            command
                .args(["bench", "transport", "--publisher", via.arg(), "--to", to])
                .args(["--index", &index.to_string()])
                .args(["--messages", &messages.to_string()])
                .args(["--size", &size.to_string()]);
            if let Some(cpu) = cpu {
                command.args(["--cpu", &cpu.to_string()]);
            }
            let mut child = command
                .stdin(Stdio::piped())
                .stdout(Stdio::piped())
                .spawn()
                .context("starting a publishing process")?;
            let stdout = BufReader::new(child.stdout.take().expect("piped"));
            publishers.children.push((child, stdout));
        }
        Ok(publishers)
    }

    /// Waits until every publisher says it is ready.
    pub(super) fn wait_ready(&mut self) -> Result<()> {
        for (_, stdout) in &mut self.children {
            let mut line = String::new();
            stdout.read_line(&mut line)?;
            ensure!(
                line.trim() == "ready",
                "a publishing process failed to start"
            );
        }
        Ok(())
    }

    pub(super) fn go(&mut self) -> Result<()> {
        for (child, _) in &mut self.children {
            child.stdin.as_mut().expect("piped").write_all(b"go\n")?;
        }
        Ok(())
    }

    /// Closes their stdin (the sign to exit) and waits for them.
    pub(super) fn finish(mut self) -> Result<()> {
        for (mut child, _) in self.children.drain(..) {
            drop(child.stdin.take());
            let status = child.wait()?;
            ensure!(status.success(), "a publishing process failed: {status}");
        }
        Ok(())
    }
}

impl Drop for Publishers {
    fn drop(&mut self) {
        for (child, _) in &mut self.children {
            let _ = child.kill();
            let _ = child.wait();
        }
    }
}

/// A publishing process: connects, says "ready", sends on "go", then waits for its stdin to
/// close (so the subscriber has read everything before its publisher goes).
pub(super) fn publish(via: Via, args: &TransportBenchArgs) -> Result<()> {
    let mut message = message_of(args.index as usize, args.size);
    let stamp = |message: &mut [u8], seq: u64| {
        let word = (u64::from(args.index) << 48) | seq;
        message[..8].copy_from_slice(&word.to_le_bytes());
    };
    if let Some(cpu) = args.cpu {
        pin_to(cpu)?;
    }
    let mut stdin = std::io::stdin().lock();
    let ready_then_go = |stdin: &mut std::io::StdinLock| -> Result<()> {
        println!("ready");
        std::io::stdout().flush()?;
        let mut go = String::new();
        stdin.read_line(&mut go)?;
        ensure!(go.trim() == "go", "the bench did not say go");
        Ok(())
    };
    match via {
        Via::Iceoryx2 | Via::Iceoryx2Latency => {
            let transport = ShmTransport::new(
                &args.to,
                &format!("bench-publisher-{}", args.index),
                limits(args),
            )?;
            let mut publisher = transport.publisher(Topic::Steps)?;
            ready_then_go(&mut stdin)?;
            for seq in 0..args.messages as u64 {
                stamp(&mut message, seq);
                if via == Via::Iceoryx2Latency {
                    std::thread::sleep(Duration::from_millis(1));
                    message[8..16].copy_from_slice(&nanos_now().to_le_bytes());
                }
                publisher.send(&message)?;
            }
            // Keep the publisher until the subscriber is done.
            std::io::copy(&mut stdin, &mut std::io::sink())?;
        }
        Via::UnixSocket => {
            let mut stream = UnixStream::connect(&args.to)
                .with_context(|| format!("connecting to {}", args.to))?;
            ready_then_go(&mut stdin)?;
            let len = u32::try_from(args.size)?.to_le_bytes();
            for seq in 0..args.messages as u64 {
                stamp(&mut message, seq);
                stream.write_all(&len)?;
                stream.write_all(&message)?;
            }
            stream.flush()?;
            std::io::copy(&mut stdin, &mut std::io::sink())?;
        }
    }
    Ok(())
}
