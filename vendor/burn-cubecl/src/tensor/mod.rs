mod base;
mod quantization;
#[cfg(feature = "tile-kernels-only")]
mod stored;

pub use base::*;
pub use quantization::*;
#[cfg(feature = "tile-kernels-only")]
pub use stored::*;
