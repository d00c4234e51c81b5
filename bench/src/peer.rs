//! The nets' peers, run in the same `bench learner`: onnxruntime (CPU provider, one thread
//! per core) on a graph built from the nets' own layers and weights ([`qnet::NetLayers`]) over
//! the same rotated inputs, its maps checked against ours; numpy's sgemm on the same
//! matrices as our matmul peak; and, where it is installed, PyTorch's training step of the
//! same net on the same weights, inputs and pixels, its loss and Q values checked against
//! ours.

use std::path::Path;

use anyhow::{Context, Result, bail};
use learner::{LearningConfig, Sample, StepReport};
use qnet::{Geometry, NetLayers, PrimitiveNet, QNets};
use serde_json::{Map, Value, json};
use sim::{Primitive, ROTATIONS};

use super::python::script_figures;

/// The same inputs and our answer on them.
pub struct PeerRun<'a> {
    pub nets: &'a QNets,
    /// Padded, rotated planes of `n` items (colour, depth, mask), as the nets take them.
    pub rotated: [&'a [f32]; 3],
    pub n: usize,
    pub padded: usize,
    /// Our low-resolution maps of the push and the grasp net on them.
    pub ours: [&'a [f32]; 2],
    pub reps: usize,
    pub threads: usize,
}

/// Runs [`ORT_SCRIPT`]: `ort_infer_ms` (both nets, median), `ort_max_rel_diff` (from our
/// maps), `sgemm_peak_gflops`, and the versions.
pub fn onnxruntime_figures(python: &Path, run: &PeerRun) -> Result<Map<String, Value>> {
    let dir = tempfile::tempdir().context("a directory for the peer's inputs")?;
    let spec = json!({
        "nets": {"push": NetLayers::of(&run.nets.push)?, "grasp": NetLayers::of(&run.nets.grasp)?},
        "n": run.n,
        "padded": run.padded,
        "reps": run.reps,
        "threads": run.threads,
    });
    std::fs::write(dir.path().join("layers.json"), serde_json::to_vec(&spec)?)?;
    let files = ["colour", "depth", "mask", "ours_push", "ours_grasp"];
    let arrays = run.rotated.iter().chain(&run.ours);
    for (name, values) in files.iter().zip(arrays) {
        write_f32(dir.path(), name, values)?;
    }
    script_figures(
        python,
        ORT_IMPORTS,
        ORT_SCRIPT,
        &[dir.path().display().to_string()],
    )
}

/// Our training step's samples on the same weights, and our first batch step's answer.
pub struct TrainingPeerRun<'a> {
    /// The trained net's weights before that step.
    pub net: &'a PrimitiveNet,
    /// Padded planes of the input's 16 rotations (colour, depth, mask), rotation `k` the
    /// `k`th: each grasp item's input.
    pub rotated: [&'a [f32]; 3],
    pub geometry: &'a Geometry,
    /// The batch step's grasps; the one-grasp step trains the first of them.
    pub samples: &'a [Sample],
    pub learning: &'a LearningConfig,
    /// Our first batch step on `net`.
    pub ours: &'a StepReport,
    pub reps: usize,
    pub threads: usize,
    /// Where PyTorch steps: `cpu`, or `cuda` beside a GPU backend of ours.
    pub device: &'a str,
}

/// Runs [`TORCH_SCRIPT`]: `torch_train_step_ms` and `torch_batch_train_step_ms` (medians),
/// `torch_max_rel_diff` (its first batch step's loss and Q values from ours), its version and
/// the device it ran on.
/// A grasp teaches its rotation and the symmetric one (the learner's items, in its order);
/// what the peer's graph does not build is refused: an equivariant net (its items share
/// passes), an outcome head (a second loss), mirrored or translated items.
pub fn torch_figures(python: &Path, run: &TrainingPeerRun) -> Result<Map<String, Value>> {
    if run.net.group() > 1 || run.net.has_outcome() {
        bail!("the peer trains ordinary nets without an outcome head");
    }
    let learning = run.learning;
    if learning.mirror_grasps || learning.translate_samples > 0 || learning.spot_q {
        bail!("the peer builds no mirrored, translated or SPOT-Q items");
    }
    if run
        .samples
        .iter()
        .any(|s| s.action.primitive != Primitive::Grasp)
    {
        bail!("the peer trains the grasp net");
    }
    let (geometry, low) = (run.geometry, run.geometry.low_side());
    let mut rotations = Vec::new();
    let mut pixel_weights = Vec::new();
    for sample in run.samples {
        let action = sample.action;
        for rotation in [
            action.rotation,
            (action.rotation + ROTATIONS / 2) % ROTATIONS,
        ] {
            let mut weights = vec![0.0; low * low];
            geometry.add_pixel_weights(rotation, (action.row, action.col), &mut weights);
            rotations.push(rotation);
            pixel_weights.extend(weights);
        }
    }
    let per_sample = rotations.len() / run.samples.len();
    let per_item = |value: fn(&Sample) -> f32| -> Vec<f32> {
        let values = run.samples.iter().map(value);
        values
            .flat_map(|v| std::iter::repeat_n(v, per_sample))
            .collect()
    };
    let spec = json!({
        "net": NetLayers::of(run.net)?,
        "padded": geometry.padded(),
        "rotations": rotations,
        "low_side": low,
        "one_grasp_items": per_sample,
        "labels": per_item(|s| s.label),
        "weights": per_item(|s| s.weight),
        "huber_delta": learning.huber_delta,
        "learning_rate": learning.learning_rate,
        "betas": [learning.beta_1, learning.beta_2],
        "weight_decay": learning.weight_decay,
        "ours_loss": run.ours.loss,
        "ours_q": run.ours.predicted,
        "reps": run.reps,
        "threads": run.threads,
        "device": run.device,
    });
    let dir = tempfile::tempdir().context("a directory for the training peer's inputs")?;
    std::fs::write(dir.path().join("training.json"), serde_json::to_vec(&spec)?)?;
    for (name, values) in ["colour", "depth", "mask"].iter().zip(run.rotated) {
        write_f32(dir.path(), name, values)?;
    }
    write_f32(dir.path(), "pixel_weights", &pixel_weights)?;
    script_figures(
        python,
        TORCH_IMPORTS,
        TORCH_SCRIPT,
        &[dir.path().display().to_string()],
    )
}

/// `values` as little-endian f32 in `dir/name.f32`, the peers' input format.
fn write_f32(dir: &Path, name: &str, values: &[f32]) -> Result<()> {
    let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
    std::fs::write(dir.join(format!("{name}.f32")), bytes)
        .with_context(|| format!("writing the peer's {name}.f32"))
}

const ORT_IMPORTS: &str = "import numpy as np
import onnx
import onnxruntime as ort
from onnx import helper, numpy_helper, TensorProto";

/// Builds the ONNX graph of both nets from `layers.json` (each trunk over its plane,
/// concatenated, the fused context, the head), runs it with onnxruntime on the `.f32` inputs
/// beside it, and times numpy's sgemm. Prints one JSON object.
const ORT_SCRIPT: &str = r#"
folder = sys.argv[1]
spec = json.load(open(os.path.join(folder, "layers.json")))
n, p, reps, threads = spec["n"], spec["padded"], spec["reps"], spec["threads"]
nodes, initialisers = [], []

def fresh(prefix):
    return f"{prefix}{len(nodes)}_{len(initialisers)}"

def constant(values, shape):
    name = fresh("c")
    array = np.asarray(values, dtype=np.float32).reshape(shape)
    initialisers.append(numpy_helper.from_array(array, name))
    return name

def apply(layers, x):
    for layer in layers:
        y = fresh("t")
        if layer["op"] == "conv":
            out, _, k, _ = layer["shape"]
            args = [x, constant(layer["weight"], layer["shape"]), constant(layer["bias"], [out])]
            nodes.append(helper.make_node(
                "Conv", args, [y], kernel_shape=[k, k], strides=[layer["stride"]] * 2,
                dilations=[layer["dilation"]] * 2, pads=[layer["padding"]] * 4))
        elif layer["op"] == "batch_norm":
            c = len(layer["gamma"])
            args = [x] + [constant(layer[key], [c]) for key in ("gamma", "beta", "mean", "var")]
            nodes.append(helper.make_node(
                "BatchNormalization", args, [y], epsilon=float(layer["epsilon"])))
        else:
            nodes.append(helper.make_node("Relu", [x], [y]))
        x = y
    return x

planes = [("colour", 3), ("depth", 1), ("mask", 1)]
outputs = []
for name in ("push", "grasp"):
    net = spec["nets"][name]
    features = [apply(trunk, plane) for trunk, (plane, _) in zip(net["trunks"], planes)]
    joined = fresh("cat")
    nodes.append(helper.make_node("Concat", features, [joined], axis=1))
    outputs.append(apply(net["head"], apply(net["fused"], joined)))
inputs = [helper.make_tensor_value_info(plane, TensorProto.FLOAT, [n, c, p, p])
          for plane, c in planes]
results = [helper.make_tensor_value_info(o, TensorProto.FLOAT, None) for o in outputs]
graph = helper.make_graph(nodes, "qnets", inputs, results, initialisers)
model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
# make_model stamps the installed onnx's newest IR version, which an older onnxruntime refuses
# ("Unsupported model IR version"); opset 17 came with IR version 8.
model.ir_version = 8

options = ort.SessionOptions()
options.intra_op_num_threads = threads
options.inter_op_num_threads = 1
session = ort.InferenceSession(model.SerializeToString(), options,
                               providers=["CPUExecutionProvider"])
feed = {plane: np.fromfile(os.path.join(folder, f"{plane}.f32"), dtype="<f4").reshape(n, c, p, p)
        for plane, c in planes}
maps = session.run(None, feed)
worst = 0.0
for name, got in zip(("push", "grasp"), maps):
    ours = np.fromfile(os.path.join(folder, f"ours_{name}.f32"), dtype="<f4").reshape(got.shape)
    worst = max(worst, float(np.abs(got - ours).max() / max(np.abs(ours).max(), 1e-30)))
times = []
for _ in range(reps):
    start = time.perf_counter()
    session.run(None, feed)
    times.append(time.perf_counter() - start)
times.sort()

size = 1024
rng = np.random.default_rng(0)
a = rng.random((size, size), dtype=np.float32)
b = rng.random((size, size), dtype=np.float32)
a @ b
gemm_times = []
for _ in range(max(reps, 3)):
    start = time.perf_counter()
    a @ b
    gemm_times.append(time.perf_counter() - start)
print(json.dumps({
    "ort_version": ort.__version__,
    "numpy_version": np.__version__,
    "ort_infer_ms": 1e3 * times[len(times) // 2],
    "ort_max_rel_diff": worst,
    "sgemm_peak_gflops": 2.0 * size ** 3 / min(gemm_times) / 1e9,
}))
"#;

const TORCH_IMPORTS: &str = "import numpy as np
import torch";

/// Builds the trained net in PyTorch from `training.json` (each trunk over its plane,
/// concatenated, the fused context, the head; a convolution followed by a batch norm has no
/// bias, as in ours), on the weights given, in training mode (batch statistics); steps it
/// with Adam on the weighted Huber loss of each item's Q value (its low-resolution map
/// weighted at its pixel, as ours), first on the whole batch to check the loss and Q values
/// against ours, then timed on the one grasp's items and the batch. On CUDA it computes in
/// fp32 as ours does (no TF32) and lets cuDNN pick its fastest algorithms (the warm-up step
/// does); each timed step ends by reading its loss back, which waits for the device.
/// Prints one JSON object.
const TORCH_SCRIPT: &str = r#"
folder = sys.argv[1]
spec = json.load(open(os.path.join(folder, "training.json")))
torch.set_num_threads(spec["threads"])
p, s, reps = spec["padded"], spec["low_side"], spec["reps"]
if spec["device"] == "cuda":
    if not torch.cuda.is_available():
        raise SystemExit("PyTorch sees no CUDA device")
    torch.backends.cuda.matmul.allow_tf32 = False
    torch.backends.cudnn.allow_tf32 = False
    torch.backends.cudnn.benchmark = True
    device_name = torch.cuda.get_device_name()
else:
    device_name = "cpu"
device = torch.device(spec["device"])

def conv(layer, bias):
    out, inp, k, _ = layer["shape"]
    module = torch.nn.Conv2d(inp, out, k, stride=layer["stride"], padding=layer["padding"],
                             dilation=layer["dilation"], bias=bias)
    with torch.no_grad():
        module.weight.copy_(torch.tensor(layer["weight"]).reshape(layer["shape"]))
        if bias:
            module.bias.copy_(torch.tensor(layer["bias"]))
    return module

def norm(layer):
    module = torch.nn.BatchNorm2d(len(layer["gamma"]), eps=layer["epsilon"])
    with torch.no_grad():
        for name, key in (("weight", "gamma"), ("bias", "beta"),
                          ("running_mean", "mean"), ("running_var", "var")):
            getattr(module, name).copy_(torch.tensor(layer[key]))
    return module

def sequence(layers):
    modules = []
    for i, layer in enumerate(layers):
        if layer["op"] == "conv":
            normed = i + 1 < len(layers) and layers[i + 1]["op"] == "batch_norm"
            modules.append(conv(layer, not normed))
        elif layer["op"] == "batch_norm":
            modules.append(norm(layer))
        else:
            modules.append(torch.nn.ReLU())
    return torch.nn.Sequential(*modules)

class Net(torch.nn.Module):
    def __init__(self, layers):
        super().__init__()
        self.trunks = torch.nn.ModuleList(sequence(t) for t in layers["trunks"])
        self.fused = sequence(layers["fused"])
        self.head = sequence(layers["head"])

    def forward(self, planes):
        features = torch.cat([t(x) for t, x in zip(self.trunks, planes)], 1)
        return self.head(self.fused(features))

net = Net(spec["net"]).train().to(device)
optimiser = torch.optim.Adam(net.parameters(), lr=spec["learning_rate"], betas=spec["betas"],
                             eps=1e-5, weight_decay=spec["weight_decay"])
rotations = torch.tensor(spec["rotations"])
planes = [torch.from_numpy(np.fromfile(os.path.join(folder, f"{name}.f32"), dtype="<f4")
                           .reshape(16, c, p, p))[rotations]
          for name, c in (("colour", 3), ("depth", 1), ("mask", 1))]
planes = [x.to(device) for x in planes]
pixel = torch.from_numpy(np.fromfile(os.path.join(folder, "pixel_weights.f32"), dtype="<f4")
                         .reshape(len(rotations), s, s)).to(device)
labels = torch.tensor(spec["labels"], device=device)
weights = torch.tensor(spec["weights"], device=device)

def batch(n):
    return [[x[:n].contiguous() for x in planes]] + [t[:n].contiguous()
                                                      for t in (pixel, labels, weights)]

def step(inputs, at_pixel, targets, importance):
    q = (net(inputs)[:, 0] * at_pixel).sum((1, 2))
    huber = torch.nn.functional.huber_loss(q, targets, reduction="none",
                                           delta=spec["huber_delta"])
    loss = (huber * importance).sum()
    optimiser.zero_grad(set_to_none=True)
    loss.backward()
    optimiser.step()
    return q.detach().cpu().numpy(), float(loss)

def median_ms(inputs):
    step(*inputs)
    times = []
    for _ in range(reps):
        start = time.perf_counter()
        step(*inputs)
        times.append(time.perf_counter() - start)
    return 1e3 * sorted(times)[len(times) // 2]

whole = batch(len(rotations))
q, loss = step(*whole)
per_sample = len(rotations) // len(spec["ours_q"])
ours_q = np.asarray(spec["ours_q"], dtype=np.float32)
scale = max(float(np.abs(ours_q).max()), 1e-30)
worst = max(float(np.abs(q[::per_sample] - ours_q).max()) / scale,
            abs(loss - spec["ours_loss"]) / max(abs(spec["ours_loss"]), 1e-30))
print(json.dumps({
    "torch_version": torch.__version__,
    "torch_device": device_name,
    "torch_max_rel_diff": worst,
    "torch_train_step_ms": median_ms(batch(spec["one_grasp_items"])),
    "torch_batch_train_step_ms": median_ms(whole),
}))
"#;
