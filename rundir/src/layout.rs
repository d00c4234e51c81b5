//! How a run's environments fall into actor processes: process `p` of a block that starts
//! at environment `from` plays `from + p * k ..` (`k` environments a process, the run's
//! `envs_per_actor`), here and on joined hosts alike. Environment indices are what the
//! messages, the buffer's streams and the hosts' places count; processes are what the
//! launcher starts and a joined host's `--actors` names.

/// The environments of each actor process of a run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ProcessLayout {
    envs_per_process: u32,
}

impl ProcessLayout {
    /// `envs_per_process` environments a process (0 is taken as 1).
    pub fn new(envs_per_process: u32) -> Self {
        Self {
            envs_per_process: envs_per_process.max(1),
        }
    }

    /// The environments of `processes` actor processes.
    pub fn environments(self, processes: u32) -> u32 {
        processes * self.envs_per_process
    }

    /// The actor processes of `environments` environments (whole processes).
    pub fn processes(self, environments: u32) -> u32 {
        environments / self.envs_per_process
    }

    /// The first environment of each of `processes` actor processes whose environments
    /// start at `from`.
    pub fn first_environments(
        self,
        from: u32,
        processes: u32,
    ) -> impl Iterator<Item = u32> + use<> {
        let k = self.envs_per_process;
        (0..processes).map(move |p| from + p * k)
    }

    /// The first environment of the actor process that plays `environment` (processes start
    /// at multiples of the layout's environments a process).
    pub fn process_of(self, environment: u32) -> u32 {
        environment - environment % self.envs_per_process
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn environments_and_processes_map_both_ways() {
        let layout = ProcessLayout::new(4);
        assert_eq!(layout.environments(3), 12);
        assert_eq!(layout.processes(12), 3);
        assert_eq!(
            layout.first_environments(8, 3).collect::<Vec<_>>(),
            [8, 12, 16]
        );
        assert_eq!(layout.process_of(13), 12);
        assert_eq!(layout.process_of(12), 12);
        let one = ProcessLayout::new(0);
        assert_eq!((one.environments(3), one.process_of(5)), (3, 5));
    }
}
