//! How long a stretch of a role's work took by the wall clock, and what it cost in CPU time:
//! the second leaves out the time the role waited (on the rate limiter, or for a core other
//! processes held), so it gives a run's cost per action or per update; and the memory a
//! process holds ([`status_mb`]).

use std::time::Instant;

/// When a stretch of work began, by the wall clock and by this process's CPU clock.
#[derive(Clone, Copy, Debug)]
pub struct Stopwatch {
    wall: Instant,
    cpu_s: f64,
}

impl Stopwatch {
    pub fn start() -> Self {
        Self {
            wall: Instant::now(),
            cpu_s: process_cpu_s(),
        }
    }

    /// Seconds since the start.
    pub fn wall_s(&self) -> f64 {
        self.wall.elapsed().as_secs_f64()
    }

    /// CPU seconds this process used since the start, all its threads, user and system.
    pub fn cpu_s(&self) -> f64 {
        process_cpu_s() - self.cpu_s
    }
}

/// This process's CPU time so far.
fn process_cpu_s() -> f64 {
    let mut now = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `now` is a valid `timespec` for the call to write; the clock exists on every
    // Unix this runs on (POSIX), and on failure `now` stays zero.
    unsafe { libc::clock_gettime(libc::CLOCK_PROCESS_CPUTIME_ID, &mut now) };
    now.tv_sec as f64 + now.tv_nsec as f64 * 1e-9
}

/// A size line ("VmRSS:", "VmHWM:") of `/proc/<process>/status` in MB (`process`: a pid or
/// `self`), where there is one.
pub fn status_mb(process: &str, field: &str) -> Option<f64> {
    let status = std::fs::read_to_string(format!("/proc/{process}/status")).ok()?;
    let line = status.lines().find(|line| line.starts_with(field))?;
    let kb: f64 = line[field.len()..]
        .trim()
        .trim_end_matches("kB")
        .trim()
        .parse()
        .ok()?;
    Some(kb / 1024.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cpu_time_counts_work_and_not_sleep() {
        let watch = Stopwatch::start();
        std::thread::sleep(std::time::Duration::from_millis(200));
        let slept = watch.cpu_s();
        // Work until the CPU clock says 150 ms of it were done: on a loaded machine that
        // takes longer by the wall clock, but it must get there.
        let mut x = 1u64;
        let busy = Instant::now();
        while watch.cpu_s() - slept < 0.15 && busy.elapsed().as_secs() < 20 {
            for _ in 0..10_000 {
                x = std::hint::black_box(x.wrapping_mul(6364136223846793005).wrapping_add(1));
            }
        }
        let worked = watch.cpu_s() - slept;
        assert!(watch.wall_s() >= 0.2 + worked - 0.05);
        assert!(slept < 0.1, "sleeping cost {slept} CPU seconds");
        assert!(worked >= 0.15, "20 s of work cost {worked} CPU seconds");
    }
}
