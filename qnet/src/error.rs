use thiserror::Error;

#[derive(Debug, Error)]
pub enum QNetError {
    #[error("the networks' weights do not load: {0}")]
    Weights(String),
    #[error("rotation {0} is out of range (0..16)")]
    Rotation(u8),
    #[error("the input is {got} x {got} but the geometry is for {want} x {want}")]
    Side { got: usize, want: usize },
    #[error("pixel ({row}, {col}) is outside the {side} x {side} heightmap")]
    Pixel { row: usize, col: usize, side: usize },
    #[error("the wgpu backend: {0}")]
    Backend(String),
    #[error(transparent)]
    QMaps(#[from] policy::PolicyError),
}
