//! Which backend runs the nets — the CPU (burn-flex) or a GPU through burn-wgpu — and the
//! device it opens, with the adapter a GPU backend landed on.
//!
//! A config names the backend (`[backend]`); a build without the `wgpu` feature, or a machine
//! with no adapter, refuses `wgpu` with what to do, when the device is opened (the launcher
//! opens every backend a run names before it starts a role).

use std::fmt;
use std::path::PathBuf;
use std::str::FromStr;

use burn::tensor::Device;
use serde::{Deserialize, Serialize};

use crate::error::QNetError;

#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Backend {
    /// burn-flex on this machine's cores (the nets' inference form for acting).
    #[default]
    Cpu,
    /// burn-wgpu: Vulkan, Metal, DirectX 12 or OpenGL, on a GPU or a software rasterizer.
    Wgpu,
}

/// A backend's device, opened, and the adapter it runs on (none for the CPU).
#[derive(Clone, Debug)]
pub struct OpenDevice {
    pub device: Device,
    pub adapter: Option<Adapter>,
}

/// The graphics adapter a wgpu device runs on, as wgpu reports it.
#[derive(Clone, Debug)]
pub struct Adapter {
    /// e.g. `NVIDIA H100 80GB HBM3`, `llvmpipe (LLVM 15.0.6, 256 bits)`.
    pub name: String,
    /// The driver's name and version, e.g. `llvmpipe Mesa 22.3.6`.
    pub driver: String,
    /// The graphics API, e.g. `Vulkan`.
    pub api: String,
    /// `DiscreteGpu`, `IntegratedGpu`, `Cpu` (a software rasterizer), ...
    pub kind: String,
}

impl fmt::Display for Adapter {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{} ({}; driver {}; {})",
            self.name, self.kind, self.driver, self.api
        )
    }
}

impl Backend {
    pub fn name(self) -> &'static str {
        match self {
            Backend::Cpu => "cpu",
            Backend::Wgpu => "wgpu",
        }
    }

    /// The backend's device, ready to use. Opening `wgpu` chooses and starts its adapter
    /// once per process (later calls share it).
    pub fn open(self) -> Result<OpenDevice, QNetError> {
        match self {
            Backend::Cpu => Ok(OpenDevice {
                device: Device::flex(),
                adapter: None,
            }),
            Backend::Wgpu => gpu::open(),
        }
    }
}

impl fmt::Display for Backend {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Backend {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "cpu" => Ok(Backend::Cpu),
            "wgpu" => Ok(Backend::Wgpu),
            _ => Err(format!("`{s}` is not a backend: cpu or wgpu")),
        }
    }
}

/// Where CubeCL keeps its autotune results on disk, for every process of every run on this
/// machine to load instead of tuning again: `$PUSHGRASP_TUNE_CACHE`, else `pushgrasp/tune`
/// in the user's cache directory (`$XDG_CACHE_HOME`, else `~/.cache`); `None` with neither
/// (CubeCL then picks a place). Results are keyed by the device, its driver and CubeCL's
/// version, so one directory serves every GPU of the machine.
pub fn tune_cache() -> Option<PathBuf> {
    let set = |name: &str| std::env::var_os(name).filter(|value| !value.is_empty());
    if let Some(dir) = set("PUSHGRASP_TUNE_CACHE") {
        return Some(dir.into());
    }
    let cache = set("XDG_CACHE_HOME")
        .map(PathBuf::from)
        .or_else(|| set("HOME").map(|home| PathBuf::from(home).join(".cache")))?;
    Some(cache.join("pushgrasp").join("tune"))
}

#[cfg(feature = "wgpu")]
mod gpu {
    use std::sync::OnceLock;

    use burn::cubecl::config::{CubeClRuntimeConfig, RuntimeConfig};
    use burn::tensor::Device;

    use super::{Adapter, OpenDevice};
    use crate::error::QNetError;

    /// burn registers a wgpu device once per process: the first opening's result is kept.
    static OPENED: OnceLock<Result<OpenDevice, String>> = OnceLock::new();

    pub fn open() -> Result<OpenDevice, QNetError> {
        OPENED
            .get_or_init(|| {
                if let Some(dir) = super::tune_cache() {
                    // CubeCL roots its caches where its config says when it loads the
                    // config (a `cubecl.toml`, else beside the nearest Cargo.toml): loaded
                    // first, so that this root stands.
                    let _ = <CubeClRuntimeConfig as RuntimeConfig>::get();
                    burn::cubecl::environment::set_root(dir);
                }
                let (device, setup) = Device::wgpu_options()
                    .init_with_setup()
                    .map_err(|e| format!("{e}. {}", what_to_do()))?;
                let info = setup.adapter.get_info();
                if info.device_type == burn::cubecl::wgpu::wgpu::DeviceType::Cpu
                    && std::env::var_os("PUSHGRASP_TUNE_SOFTWARE").is_none()
                {
                    // A tune costs a software device minutes a shape, past anything it
                    // saves: each operation runs its first kernel that serves instead.
                    burn::cubecl::tune::defer_tuning(true);
                }
                let driver = [info.driver.trim(), info.driver_info.trim()]
                    .into_iter()
                    .filter(|part| !part.is_empty())
                    .collect::<Vec<_>>()
                    .join(" ");
                Ok(OpenDevice {
                    device,
                    adapter: Some(Adapter {
                        name: info.name,
                        driver,
                        api: format!("{:?}", info.backend),
                        kind: format!("{:?}", info.device_type),
                    }),
                })
            })
            .clone()
            .map_err(QNetError::Backend)
    }

    /// CubeCL's variable that chooses the adapter instead of wgpu's high-performance one.
    const ADAPTER_VAR: &str = "CUBECL_WGPU_DEFAULT_DEVICE";

    /// What to do when no device opened: with the adapter chosen by [`ADAPTER_VAR`], what it
    /// takes (its value, not the machine, is what to check first); else what to install.
    fn what_to_do() -> String {
        match std::env::var(ADAPTER_VAR) {
            Ok(value) => format!(
                "{ADAPTER_VAR}={value:?} chooses the adapter: it takes DiscreteGpu(N), \
                 IntegratedGpu(N), VirtualGpu(N) or Other(N), N counted from 0 among the \
                 adapters of that kind, or Cpu; unset, wgpu's high-performance adapter"
            ),
            Err(_) => "Install the Vulkan loader (Debian's `libvulkan1`) and the GPU's Vulkan \
                       driver (NVIDIA's loads through libglvnd: `libglvnd0`), or for a software \
                       device Mesa's lavapipe (`mesa-vulkan-drivers`); or use the cpu backend"
                .to_string(),
        }
    }
}

#[cfg(not(feature = "wgpu"))]
mod gpu {
    use super::OpenDevice;
    use crate::error::QNetError;

    pub fn open() -> Result<OpenDevice, QNetError> {
        Err(QNetError::Backend(
            "this build has no wgpu backend: build with `cargo build --release --features wgpu` \
             or use the cpu backend"
                .into(),
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn backends_read_as_their_names_and_nothing_else() {
        for backend in [Backend::Cpu, Backend::Wgpu] {
            assert_eq!(backend.name().parse::<Backend>(), Ok(backend));
        }
        let error = "gpu".parse::<Backend>().unwrap_err();
        assert!(error.contains("cpu or wgpu"), "{error}");
    }

    #[test]
    fn the_cpu_opens_without_an_adapter() {
        let open = Backend::Cpu.open().unwrap();
        assert_eq!(open.device, Device::flex());
        assert!(open.adapter.is_none());
    }

    #[cfg(not(feature = "wgpu"))]
    #[test]
    fn wgpu_in_a_build_without_it_says_how_to_build_it() {
        let error = Backend::Wgpu.open().unwrap_err().to_string();
        assert!(error.contains("--features wgpu"), "{error}");
    }
}
