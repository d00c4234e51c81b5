//! CPU time of this process's threads, by the part of a GPU backend's path they run. burn's
//! fusion runs on CubeCL's upstream device-service thread (named `DSU-<device>`), CubeCL's
//! compute server, which encodes and submits the kernels, on its downstream one (`DSD-...`);
//! the rest is the caller, rayon's workers and the driver's threads. The three run one after
//! another a kernel and overlap across kernels, so the busiest bounds a step that the device
//! keeps up with. A device slower than the host (a software one) fills their queues, and
//! they spin while they wait: their time then follows the device, not the host's work.

/// CPU seconds so far, by part.
#[derive(Clone, Copy, Debug, Default)]
pub struct ThreadCpu {
    pub fusion_s: f64,
    pub server_s: f64,
    pub other_s: f64,
}

impl ThreadCpu {
    /// The threads' CPU time now (`/proc/self/task/*/schedstat`); `None` where the kernel
    /// does not keep it. A thread that ends between two readings takes its time with it.
    pub fn now() -> Option<Self> {
        let mut total = Self::default();
        for task in std::fs::read_dir("/proc/self/task").ok()?.flatten() {
            let read = |file| std::fs::read_to_string(task.path().join(file));
            let (Ok(name), Ok(schedstat)) = (read("comm"), read("schedstat")) else {
                continue;
            };
            let on_cpu_ns: f64 = schedstat.split_whitespace().next()?.parse().ok()?;
            let part = match name.get(..4) {
                Some("DSU-") => &mut total.fusion_s,
                Some("DSD-") => &mut total.server_s,
                _ => &mut total.other_s,
            };
            *part += on_cpu_ns * 1e-9;
        }
        Some(total)
    }

    /// The time used since `start`.
    pub fn since(self, start: Self) -> Self {
        Self {
            fusion_s: self.fusion_s - start.fusion_s,
            server_s: self.server_s - start.server_s,
            other_s: self.other_s - start.other_s,
        }
    }
}
