mod backward;
mod base;
#[cfg(all(feature = "autotune", not(feature = "tile-kernels-only")))]
mod bounds;
#[cfg(feature = "tile-kernels-only")]
mod tile_kernels;
#[cfg(all(feature = "autotune", not(feature = "tile-kernels-only")))]
mod tune;

pub use backward::*;
pub use base::*;
#[cfg(feature = "tile-kernels-only")]
pub use tile_kernels::*;
#[cfg(all(feature = "autotune", not(feature = "tile-kernels-only")))]
pub use tune::*;
