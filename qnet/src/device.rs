//! Which device the networks run on: the CPU backend unless the `wgpu` feature is built and
//! `PUSHGRASP_DEVICE=cpu` does not ask otherwise.

use burn::tensor::Device;

/// The device to run on.
pub fn default_device() -> Device {
    #[cfg(feature = "wgpu")]
    if std::env::var("PUSHGRASP_DEVICE").as_deref() != Ok("cpu") {
        return Device::wgpu(burn::tensor::DeviceKind::DefaultDevice);
    }
    Device::flex()
}

/// A short name of the backend a device belongs to, for reports.
pub fn backend_name(device: &Device) -> String {
    let name = format!("{device:?}");
    if name.to_lowercase().contains("wgpu") {
        "wgpu".into()
    } else {
        "flex".into()
    }
}
