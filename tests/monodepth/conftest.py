"""Tiny ONNX networks built by the tests (with the ``onnx`` package), so the results are
known exactly: nothing is downloaded."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

NetFactory = Callable[..., Path]


@pytest.fixture
def make_net(tmp_path: Path) -> NetFactory:
    """``make_net(kind, height, width, constant=None, channels=3, dynamic=False)`` writes a
    network and returns its path.

    kinds: ``mean`` returns the mean over the colour channels of the (normalised) input, so an
    image whose grey value is an affine function of inverse depth gives exactly that;
    ``constant`` returns ``constant`` (an (H, W) map baked into the model) plus 0 x the input's
    mean, i.e. an oracle output of known shape.
    """
    import onnx
    from onnx import TensorProto, helper

    def build(kind: str, height: int, width: int, constant: np.ndarray | None = None,
              channels: int = 3, dynamic: bool = False) -> Path:
        hdim: int | str = "H" if dynamic else height
        wdim: int | str = "W" if dynamic else width
        x = helper.make_tensor_value_info("image", TensorProto.FLOAT, [1, channels, hdim, wdim])
        y = helper.make_tensor_value_info("depth", TensorProto.FLOAT, [1, hdim, wdim])
        nodes = [helper.make_node("ReduceMean", ["image"], ["m"], axes=[1], keepdims=0)]
        inits = []
        if kind == "mean":
            nodes.append(helper.make_node("Identity", ["m"], ["depth"]))
        elif kind == "constant":
            assert constant is not None
            inits.append(helper.make_tensor("c", TensorProto.FLOAT, [1, height, width],
                                            constant.astype(np.float32).ravel().tolist()))
            inits.append(helper.make_tensor("zero", TensorProto.FLOAT, [], [0.0]))
            nodes += [helper.make_node("Mul", ["m", "zero"], ["m0"]),
                      helper.make_node("Add", ["m0", "c"], ["depth"])]
        else:
            raise ValueError(kind)
        graph = helper.make_graph(nodes, f"tiny_{kind}", [x], [y], initializer=inits)
        model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)])
        model.ir_version = 8
        onnx.checker.check_model(model)
        path = tmp_path / f"{kind}_{channels}_{height}x{width}{'_dyn' if dynamic else ''}.onnx"
        onnx.save(model, str(path))
        return path

    return build


FASTDEPTH = Path(__file__).resolve().parents[1] / "data" / "models" / "fastdepth_224" / \
    "fastdepth_224.onnx"


@pytest.fixture(scope="session")
def fastdepth() -> Path:
    """FastDepth (MIT, NYU Depth v2, 5.4 MB ONNX) shipped in tests/data with its notice: a real
    network, metric as learned indoors; input RGB in [0, 1] without mean/std."""
    assert FASTDEPTH.is_file(), f"{FASTDEPTH} is missing (it is committed with the tests)"
    return FASTDEPTH
