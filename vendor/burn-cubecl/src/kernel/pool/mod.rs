mod avg_pool3d;
mod base;
mod max_pool3d;

pub(crate) use avg_pool3d::*;
pub(crate) use base::*;
pub(crate) use max_pool3d::*;
