//! Unix sockets measured: the same bytes as through shared memory, length-prefixed over a
//! socket per publishing process.

use std::io::{ErrorKind, Read};
use std::os::unix::net::{UnixListener, UnixStream};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, ensure};

use super::args::{TransportBenchArgs, Via};
use super::message::{checksum, header, message_of};
use super::publishers::Publishers;

/// Removes a file when dropped (the socket, whatever happens).
pub(super) struct RemoveOnDrop(pub(super) PathBuf);

impl Drop for RemoveOnDrop {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
    }
}

/// Time for `publishers` processes to send `messages` each over their own Unix socket to one
/// receiver, which reads every length-prefixed message into a buffer and reads every byte of
/// it, as the iceoryx2 subscriber does in place (one thread, polling the sockets in turn, as
/// the iceoryx2 subscriber polls its publishers).
pub(super) fn socket_bandwidth(
    args: &TransportBenchArgs,
    socket: &Path,
    publishers: usize,
    messages: usize,
) -> Result<Duration> {
    let _ = std::fs::remove_file(socket);
    let listener = UnixListener::bind(socket).context("binding the Unix socket")?;
    let to = socket.to_str().context("the socket path is not UTF-8")?;
    let mut children =
        Publishers::start(Via::UnixSocket, to, publishers, messages, args.size, None)?;
    listener.set_nonblocking(true)?;
    let mut streams: Vec<Frames> = Vec::new();
    let deadline = Instant::now() + Duration::from_secs(30);
    while streams.len() < publishers {
        match listener.accept() {
            Ok((stream, _)) => {
                stream.set_nonblocking(true)?;
                streams.push(Frames::new(stream, args.size));
            }
            Err(e) if e.kind() == ErrorKind::WouldBlock => {
                ensure!(
                    Instant::now() < deadline,
                    "the publishing processes did not connect"
                );
                std::thread::sleep(Duration::from_millis(1));
            }
            Err(e) => return Err(e.into()),
        }
    }
    children.wait_ready()?;
    let total = messages * publishers;
    let mut received = 0;
    let mut sums = Vec::with_capacity(total);
    let start = Instant::now();
    children.go()?;
    while received < total {
        let mut progress = false;
        for stream in &mut streams {
            let (messages, read) = stream.read_available(&mut |message| {
                sums.push((header(message).0, checksum(message)));
            })?;
            received += messages;
            progress |= read;
        }
        if !progress {
            std::thread::yield_now();
        }
    }
    let time = start.elapsed();
    let expected: Vec<u64> = (0..publishers)
        .map(|index| checksum(&message_of(index, args.size)))
        .collect();
    let wrong = sums
        .iter()
        .filter(|&&(index, sum)| expected.get(index) != Some(&sum))
        .count();
    ensure!(wrong == 0, "{wrong} messages arrived changed");
    children.finish()?;
    drop(listener);
    let _ = std::fs::remove_file(socket);
    Ok(time)
}

/// Length-prefixed messages arriving on a non-blocking Unix socket.
struct Frames {
    stream: UnixStream,
    len: [u8; 4],
    len_read: usize,
    message: Vec<u8>,
    message_read: usize,
}

impl Frames {
    fn new(stream: UnixStream, size: usize) -> Self {
        Self {
            stream,
            len: [0; 4],
            len_read: 0,
            message: vec![0; size],
            message_read: 0,
        }
    }

    /// Reads what the socket holds, handing each complete message to `sink`: (messages
    /// completed, whether any byte came).
    fn read_available(&mut self, sink: &mut dyn FnMut(&[u8])) -> Result<(usize, bool)> {
        let (mut messages, mut any) = (0, false);
        loop {
            let read = if self.len_read < 4 {
                self.stream.read(&mut self.len[self.len_read..])
            } else {
                let len = u32::from_le_bytes(self.len) as usize;
                ensure!(len == self.message.len(), "a {len}-byte message arrived");
                self.stream.read(&mut self.message[self.message_read..])
            };
            let n = match read {
                Ok(0) => return Ok((messages, any)),
                Ok(n) => n,
                Err(e) if e.kind() == ErrorKind::WouldBlock => return Ok((messages, any)),
                Err(e) if e.kind() == ErrorKind::Interrupted => continue,
                Err(e) => return Err(e.into()),
            };
            any = true;
            if self.len_read < 4 {
                self.len_read += n;
            } else {
                self.message_read += n;
                if self.message_read == self.message.len() {
                    sink(&self.message);
                    messages += 1;
                    self.len_read = 0;
                    self.message_read = 0;
                }
            }
        }
    }
}
