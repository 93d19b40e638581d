"""packlab.policies.onnx_model.new_session: the CPU session every shipped ONNX policy runs in."""

from __future__ import annotations

import numpy as np
import pytest

from packlab.policies.onnx_model import new_session


def test_sessions_flush_denormals_to_zero(tmp_path):
    """Softmax under a causal mask makes denormal floats, which x86 handles in microcode (the
    pointer LM's softmax ran 7x slower for them): the session flushes them to zero."""
    onnx = pytest.importorskip("onnx")
    pytest.importorskip("onnxruntime")
    from onnx import TensorProto, helper

    value = helper.make_tensor_value_info
    graph = helper.make_graph(
        [helper.make_node("Mul", ["x", "y"], ["z"])],
        "denormal",
        [value("x", TensorProto.FLOAT, [1]), value("y", TensorProto.FLOAT, [1])],
        [value("z", TensorProto.FLOAT, [1])],
    )
    path = tmp_path / "mul.onnx"
    onnx.save(helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)]), path)
    x, y = np.array([1e-30], np.float32), np.array([1e-10], np.float32)
    assert 0 < float(x[0]) * float(y[0]) < np.finfo(np.float32).tiny  # a denormal product
    (z,) = new_session(path).run(["z"], {"x": x, "y": y})
    assert z[0] == 0.0
