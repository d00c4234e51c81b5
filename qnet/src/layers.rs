//! A primitive net as a plain list of layers with their values, for other engines to build
//! the same function from (the onnxruntime peer of `pushgrasp bench learner`).

use burn::nn::BatchNorm;
use burn::nn::conv::Conv2d;
use serde::Serialize;

use crate::error::QNetError;
use crate::inference::{even_padding, values};
use crate::net::{PrimitiveNet, Trunk};

/// [`PrimitiveNet::forward`] in layers: each trunk over its planes (colour, depth, mask),
/// their outputs concatenated along the channels, then `fused`, then `head`.
#[derive(Clone, Debug, Serialize)]
pub struct NetLayers {
    pub trunks: [Vec<Layer>; 3],
    pub fused: Vec<Layer>,
    pub head: Vec<Layer>,
}

#[derive(Clone, Debug, Serialize)]
#[serde(tag = "op", rename_all = "snake_case")]
pub enum Layer {
    /// A square convolution: weights `[out, in, k, k]` row-major.
    Conv {
        shape: [usize; 4],
        weight: Vec<f32>,
        bias: Vec<f32>,
        stride: usize,
        dilation: usize,
        padding: usize,
    },
    /// Batch norm on running statistics.
    BatchNorm {
        gamma: Vec<f32>,
        beta: Vec<f32>,
        mean: Vec<f32>,
        var: Vec<f32>,
        epsilon: f64,
    },
    Relu,
}

impl NetLayers {
    /// `net`'s layers, laid out in full ([`PrimitiveNet::expanded`]).
    pub fn of(net: &PrimitiveNet) -> Result<Self, QNetError> {
        let net = &net.expanded();
        let trunk = |trunk: &Trunk| -> Result<Vec<Layer>, QNetError> {
            let mut layers = Vec::new();
            for block in &trunk.blocks {
                layers.extend([conv(&block.conv)?, norm(&block.norm)?, Layer::Relu]);
            }
            Ok(layers)
        };
        Ok(Self {
            trunks: [trunk(&net.colour)?, trunk(&net.depth)?, trunk(&net.mask)?],
            fused: trunk(&net.fused)?,
            head: vec![
                norm(&net.head_norm_in)?,
                Layer::Relu,
                conv(&net.head_hidden)?,
                norm(&net.head_norm_hidden)?,
                Layer::Relu,
                conv(&net.head_out)?,
            ],
        })
    }
}

fn conv(conv: &Conv2d) -> Result<Layer, QNetError> {
    let shape = conv.weight.dims();
    Ok(Layer::Conv {
        shape,
        weight: values(conv.weight.val())?,
        bias: match &conv.bias {
            Some(bias) => values(bias.val())?,
            None => vec![0.0; shape[0]],
        },
        stride: conv.stride[0],
        dilation: conv.dilation[0],
        padding: even_padding(conv)?,
    })
}

fn norm(norm: &BatchNorm) -> Result<Layer, QNetError> {
    Ok(Layer::BatchNorm {
        gamma: values(norm.gamma.val())?,
        beta: values(norm.beta.val())?,
        mean: values(norm.running_mean.value())?,
        var: values(norm.running_var.value())?,
        epsilon: norm.epsilon,
    })
}
