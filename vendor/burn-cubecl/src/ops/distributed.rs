use burn_backend::distributed::DistributedOps;

use crate::CubeBackend;

impl DistributedOps<Self> for CubeBackend {}
