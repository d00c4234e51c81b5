//! Which backend the networks run on: the CPU backend (burn-flex) unless the `wgpu` feature
//! is built, and then burn-wgpu unless `PUSHGRASP_DEVICE=cpu` asks for the CPU.

use burn::tensor::Device;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Backend {
    Flex,
    #[cfg(feature = "wgpu")]
    Wgpu,
}

impl Backend {
    /// The backend this build and environment select.
    pub fn selected() -> Self {
        #[cfg(feature = "wgpu")]
        if std::env::var("PUSHGRASP_DEVICE").as_deref() != Ok("cpu") {
            return Backend::Wgpu;
        }
        Backend::Flex
    }

    pub fn device(self) -> Device {
        match self {
            Backend::Flex => Device::flex(),
            #[cfg(feature = "wgpu")]
            Backend::Wgpu => Device::wgpu(burn::tensor::DeviceKind::DefaultDevice),
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Backend::Flex => "flex",
            #[cfg(feature = "wgpu")]
            Backend::Wgpu => "wgpu",
        }
    }
}
