"""Hand-built ONNX models whose outputs are constants encoding known boxes and masks."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def constant_model(
    path: Path,
    output0: np.ndarray,
    output1: np.ndarray,
    *,
    input_hw: tuple[int, int] | tuple[str, str] = (320, 320),
    metadata: dict[str, str] | None = None,
    extra_outputs: int = 0,
) -> Path:
    """Write a model with input ``images`` [1, 3, H, W] whose outputs are the given constants.

    The outputs add ``0 · ReduceMean(images)`` so that the graph reads its input like a real
    network. A symbolic ``input_hw`` (strings) makes a dynamic-size input.
    """
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    nodes = [
        helper.make_node("ReduceMean", ["images"], ["mean"], keepdims=0),
        helper.make_node("Mul", ["mean", "zero"], ["nothing"]),
    ]
    inits = [numpy_helper.from_array(np.zeros((), np.float32), "zero")]
    outputs = []
    for i, arr in enumerate([output0, output1] + [np.zeros((1, 2), np.float32)] * extra_outputs):
        name = f"output{i}"
        inits.append(numpy_helper.from_array(np.asarray(arr, np.float32), f"c{i}"))
        nodes.append(helper.make_node("Add", [f"c{i}", "nothing"], [name]))
        outputs.append(helper.make_tensor_value_info(name, TensorProto.FLOAT, list(arr.shape)))
    graph = helper.make_graph(
        nodes,
        "constant_seg",
        [helper.make_tensor_value_info("images", TensorProto.FLOAT, [1, 3, *input_hw])],
        outputs,
        inits,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    for k, v in (metadata or {}).items():
        model.metadata_props.add(key=k, value=v)
    onnx.checker.check_model(model)
    onnx.save(model, str(path))
    return path


def candidates(rows: list[tuple[tuple[float, float, float, float], list[float], list[float]]], nm: int = 32):
    """``output0`` [1, 4 + nc + nm, N] from rows of (cx, cy, w, h), class scores, coefficients."""
    nc = len(rows[0][1])
    out = np.zeros((1, 4 + nc + nm, len(rows)), np.float32)
    for j, (box, scores, coeffs) in enumerate(rows):
        out[0, :4, j] = box
        out[0, 4 : 4 + nc, j] = scores
        out[0, 4 + nc : 4 + nc + len(coeffs), j] = coeffs
    return out
