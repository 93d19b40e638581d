"""packlab.policies.onnx_model.new_session: the CPU session every shipped ONNX policy runs in.

Its runs flush denormal floats to zero (speed: the pointer LM's masked softmax makes them), and
only its runs: the caller's floating-point state is as it was after creating and running one.
"""

from __future__ import annotations

import multiprocessing as mp
import platform
import sys

import numpy as np
import pytest

from packlab.policies.onnx_model import Session, denormals_flushed, new_session

flushing_platform = pytest.mark.skipif(
    not (sys.platform.startswith("linux") and platform.machine() == "x86_64"),
    reason="denormals are flushed on x86-64 Linux only (elsewhere runs are unchanged)",
)

#: The session a forked child inherits (a session cannot be pickled, only inherited).
_INHERITED: list[Session] = []
X, Y = np.array([1e-30], np.float32), np.array([1e-10], np.float32)  # X * Y is a denormal


def _denormals_survive() -> bool:
    return sys.float_info.min / 2 > 0.0 and float(np.float32(1e-30) * np.float32(1e-10)) > 0


def _mul_session(tmp_path) -> Session:
    onnx = pytest.importorskip("onnx")
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
    return new_session(path)


def _run_in_child() -> tuple[float, bool]:
    (z,) = _INHERITED[0].run(["z"], {"x": X, "y": Y})
    return float(z[0]), _denormals_survive()


@flushing_platform
def test_runs_flush_denormals_and_leave_the_callers_floats_alone(tmp_path):
    assert _denormals_survive()
    session = _mul_session(tmp_path)
    assert _denormals_survive()  # creating it (ORT sets the flags there) changed nothing here
    (z,) = session.run(["z"], {"x": X, "y": Y})
    assert z[0] == 0.0
    assert _denormals_survive()


@flushing_platform
def test_the_flush_ends_with_its_block_even_on_an_error():
    with pytest.raises(KeyError), denormals_flushed():
        assert not _denormals_survive()
        raise KeyError("inside")
    assert _denormals_survive()


@flushing_platform
def test_a_forked_child_runs_a_session_made_before_the_fork(tmp_path):
    """A bench worker is forked after the parent built each policy once (preflight)."""
    _INHERITED[:] = [_mul_session(tmp_path)]
    try:
        with mp.get_context("fork").Pool(1) as pool:
            out = pool.apply(_run_in_child)
    finally:
        _INHERITED.clear()
    assert out == (0.0, True)
