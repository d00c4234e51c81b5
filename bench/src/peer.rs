//! The nets' peer, run in the same `bench learner`: onnxruntime (CPU provider, one thread per
//! core) on a graph built from the nets' own layers and weights ([`qnet::NetLayers`]) over
//! the same rotated inputs, its maps checked against ours; and numpy's sgemm on the same
//! matrices as our matmul peak.

use std::path::Path;

use anyhow::{Context, Result};
use qnet::{NetLayers, QNets};
use serde_json::{Map, Value, json};

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
        let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
        std::fs::write(dir.path().join(format!("{name}.f32")), bytes)?;
    }
    script_figures(python, ORT_SCRIPT, &[dir.path().display().to_string()])
}

/// Builds the ONNX graph of both nets from `layers.json` (each trunk over its plane,
/// concatenated, the fused context, the head), runs it with onnxruntime on the `.f32` inputs
/// beside it, and times numpy's sgemm. Prints one JSON object.
const ORT_SCRIPT: &str = r#"
import json, os, sys, time
try:
    import numpy as np
    import onnx
    import onnxruntime as ort
    from onnx import helper, numpy_helper, TensorProto
except ImportError as e:
    print(json.dumps({"missing": f"{e} (Python {sys.version.split()[0]})"}))
    sys.exit(0)

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
