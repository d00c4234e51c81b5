//! The floors the transports are measured against: a memcpy of the same bytes, and the same
//! work handed between two threads through plain memory.

use std::time::Instant;

use anyhow::{Result, ensure};
use wire::Topic;

use super::cpus::{on_cpu, pin_to};
use super::message::{checksum, message_of};
use crate::median;

/// Rate of copying `size`-byte buffers, `messages` times per repetition, from `sources`
/// buffers in turn into one: with one source, the floor of any transport that hands the
/// receiver its own copy (the source in cache); with many, the copy of data in no cache.
pub(super) fn memcpy_gbps(size: usize, messages: usize, reps: usize, sources: usize) -> f64 {
    let sources: Vec<Vec<u8>> = (0..sources.max(1)).map(|k| vec![k as u8; size]).collect();
    let mut target = vec![0u8; size];
    let runs = (0..reps)
        .map(|_| {
            let start = Instant::now();
            for source in sources.iter().cycle().take(messages) {
                target.copy_from_slice(std::hint::black_box(source));
                std::hint::black_box(&mut target);
            }
            (messages * size) as f64 / start.elapsed().as_secs_f64() / 1e9
        })
        .collect();
    median(runs)
}

/// Rate of handing `messages` messages of `size` bytes from a thread on CPU `writer` to one on
/// CPU `reader` through plain memory, the work of the one-publisher measurement without a
/// transport: the writer copies the message into the oldest free of as many buffers as the
/// steps topic holds (as a publisher copies into shared memory), the reader reads every byte
/// of it (the same checksum) and hands the buffer back.
pub(super) fn handoff_gbps(
    size: usize,
    messages: usize,
    reps: usize,
    reader: usize,
    writer: usize,
) -> Result<f64> {
    use std::sync::mpsc::sync_channel;
    let buffers = Topic::Steps.buffer();
    let message = message_of(0, size);
    let expected = checksum(&message);
    let mut runs = Vec::with_capacity(reps);
    for _ in 0..reps {
        let (full_tx, full_rx) = sync_channel::<Vec<u8>>(buffers);
        let (empty_tx, empty_rx) = sync_channel::<Vec<u8>>(buffers);
        for _ in 0..buffers {
            empty_tx.send(vec![0; size])?;
        }
        let message = &message;
        let time = on_cpu(reader, move || {
            std::thread::scope(|scope| {
                let writing = scope.spawn(move || -> Result<()> {
                    pin_to(writer)?;
                    for mut buffer in empty_rx.iter().take(messages) {
                        buffer.copy_from_slice(message);
                        full_tx.send(buffer)?;
                    }
                    Ok(())
                });
                let start = Instant::now();
                let mut read = 0;
                for buffer in full_rx.iter().take(messages) {
                    ensure!(checksum(&buffer) == expected, "a buffer arrived changed");
                    read += 1;
                    // The writer stops taking buffers after the last message.
                    let _ = empty_tx.send(buffer);
                }
                let time = start.elapsed();
                writing.join().expect("the writing thread panicked")?;
                ensure!(read == messages, "{read} of {messages} buffers arrived");
                Ok(time)
            })
        })?;
        runs.push((messages * size) as f64 / time.as_secs_f64() / 1e9);
    }
    Ok(median(runs))
}
