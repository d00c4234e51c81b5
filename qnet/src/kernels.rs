//! The kernels a call launches on a GPU device, counted by CubeCL as it issues them (its
//! launch observer), so a benchmark can print what a training step or a decision costs the
//! host in launches beside what it costs in time, on any device, software ones included.
//!
//! The count covers every launch issued between the call's start and the device's sync
//! after it: work the call queued but burn's fusion had not yet run (the backward pass and
//! the optimiser after a step's read) is flushed into the count, and nothing queued before
//! the call is. The observer is process-wide: launches from other threads meanwhile count
//! too, so count where nothing else runs on the device.

use burn::tensor::Device;

/// The kernels a call launched, by kernel name.
pub struct Launches {
    by_name: Vec<(String, u64)>,
}

impl Launches {
    /// Kernels launched in all.
    pub fn total(&self) -> u64 {
        self.by_name.iter().map(|(_, count)| count).sum()
    }

    /// Kernels launched per kernel name (CubeCL's short form of it), most launched first.
    pub fn by_name(&self) -> &[(String, u64)] {
        &self.by_name
    }
}

/// Runs `call` and counts the kernels it launched on `device` (see the module's note);
/// `None` where nothing is counted: the CPU backend, or a build without the `wgpu` feature.
pub fn count<T>(device: &Device, call: impl FnOnce() -> T) -> (T, Option<Launches>) {
    #[cfg(feature = "wgpu")]
    if *device != Device::flex() {
        return observed::count(device, call);
    }
    let _ = device;
    (call(), None)
}

#[cfg(feature = "wgpu")]
mod observed {
    use std::collections::HashMap;
    use std::sync::{Arc, Mutex};

    use burn::cubecl::config::{TypeNameFormatLevel, type_name_format};
    use burn::cubecl::logging::{LaunchObservation, LaunchObserver};
    use burn::tensor::Device;

    use super::Launches;

    #[derive(Default)]
    struct Tally(Mutex<HashMap<&'static str, u64>>);

    impl LaunchObserver for Tally {
        fn launched(&self, kernel: &'static str) {
            *self
                .0
                .lock()
                .expect("the tally is never left mid-update")
                .entry(kernel)
                .or_default() += 1;
        }
    }

    pub fn count<T>(device: &Device, call: impl FnOnce() -> T) -> (T, Option<Launches>) {
        // What was queued before the call runs before the count starts.
        sync(device);
        let tally = Arc::new(Tally::default());
        let watching = LaunchObservation::new(tally.clone());
        let out = call();
        sync(device);
        drop(watching);
        let counts = tally.0.lock().expect("the tally is complete").clone();
        let mut by_name: HashMap<String, u64> = HashMap::new();
        for (kernel, n) in counts {
            *by_name
                .entry(type_name_format(kernel, TypeNameFormatLevel::Short))
                .or_default() += n;
        }
        let mut by_name: Vec<(String, u64)> = by_name.into_iter().collect();
        by_name.sort_by(|a, b| b.1.cmp(&a.1).then_with(|| a.0.cmp(&b.0)));
        (out, Some(Launches { by_name }))
    }

    fn sync(device: &Device) {
        device
            .sync()
            .expect("the device runs the work it was given before a count");
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_cpu_backend_counts_nothing_and_still_runs_the_call() {
        let (value, launches) = count(&Device::flex(), || 6 * 7);
        assert_eq!(value, 42);
        assert!(launches.is_none());
    }
}
