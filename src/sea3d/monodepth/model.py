"""A user-supplied monocular depth network in ONNX, run by onnxruntime.

Nothing is downloaded: the user exports a network (e.g. Depth-Anything-V2-Small, Apache-2.0;
``docs/monodepth.md`` says how) and passes the ``.onnx`` file. The network must take one image
tensor ``(1, 3, H, W)`` (NCHW, float32) and return one map ``(1, H', W')`` or ``(1, 1, H', W')``.
The declared input size is read from the model; a dynamic size (symbolic dimensions) is chosen
from the image: longer side :attr:`MonoDepthConfig.dynamic_long_side_px`, both sides multiples
of :attr:`MonoDepthConfig.size_multiple` (14 for ViT patch sizes). The image is resized to the
input size and the output back to the image size (bilinear).

Preprocessing: RGB scaled to [0, 1], then ``imagenet`` normalisation (mean 0.485, 0.456, 0.406,
std 0.229, 0.224, 0.225, what Depth-Anything and MiDaS expect) or ``unit`` (none).

Providers: the CPU provider by default; ``device="auto"`` uses CUDA when onnxruntime offers it.
"""

from __future__ import annotations

import logging
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from sea3d._typing import F32
from sea3d.errors import ConfigError, MonoDepthError

__all__ = ["MonoDepthConfig", "OnnxDepthModel", "select_providers"]

log = logging.getLogger(__name__)
OUTPUT_KINDS = ("inverse", "depth", "metric")
_IMAGENET_MEAN = np.array([0.485, 0.456, 0.406], dtype=np.float32)
_IMAGENET_STD = np.array([0.229, 0.224, 0.225], dtype=np.float32)


@dataclass(frozen=True, kw_only=True)
class MonoDepthConfig:
    """How to run a monocular depth network.

    Attributes:
        output_kind: what the network returns: ``inverse`` (relative inverse depth, up to
            scale and shift: Depth-Anything, MiDaS; the default), ``depth`` (relative depth,
            up to scale and shift) or ``metric`` (metres).
        normalize: ``imagenet`` or ``unit`` input normalisation.
        device: ``cpu`` (default), ``cuda`` or ``auto`` (CUDA when available).
        dynamic_long_side_px: input's longer side for models with a dynamic input size.
        size_multiple: dynamic input sides are rounded to multiples of this.
        threads: onnxruntime intra-op threads (0: its default).
    """

    output_kind: str = "inverse"
    normalize: str = "imagenet"
    device: str = "cpu"
    dynamic_long_side_px: int = 518
    size_multiple: int = 14
    threads: int = 0

    def __post_init__(self) -> None:
        if self.output_kind not in OUTPUT_KINDS:
            raise ConfigError(f"output_kind must be one of {', '.join(OUTPUT_KINDS)}, got "
                              f"{self.output_kind!r}")
        if self.normalize not in ("imagenet", "unit"):
            raise ConfigError(f"normalize must be imagenet or unit, got {self.normalize!r}")
        if self.device not in ("cpu", "cuda", "auto"):
            raise ConfigError(f"device must be cpu, cuda or auto, got {self.device!r}")
        if self.dynamic_long_side_px < 16 or self.size_multiple < 1:
            raise ConfigError("dynamic_long_side_px must be >= 16 and size_multiple >= 1")


def select_providers(device: str, available: list[str]) -> list[str]:
    """onnxruntime execution providers for ``device`` given the available ones.

    Raises:
        MonoDepthError: ``cuda`` asked for but onnxruntime has no CUDA provider.
    """
    cuda = "CUDAExecutionProvider"
    if device == "cuda":
        if cuda not in available:
            raise MonoDepthError(
                f"device cuda: onnxruntime offers no CUDA provider (available: "
                f"{', '.join(available)}); install onnxruntime-gpu or use device cpu"
            )
        return [cuda, "CPUExecutionProvider"]
    if device == "auto" and cuda in available:
        return [cuda, "CPUExecutionProvider"]
    return ["CPUExecutionProvider"]


def _dim(d: Any) -> int | None:
    return int(d) if isinstance(d, int) and d > 0 else None


class OnnxDepthModel:
    """An ONNX monocular depth network.

    Args:
        path: the ``.onnx`` file.
        config: :class:`MonoDepthConfig`.

    Raises:
        MonoDepthError: the file is missing or not an ONNX model, or its input or output is not
            what a depth network has (naming the file and the shapes).
    """

    def __init__(self, path: str | os.PathLike[str],
                 config: MonoDepthConfig | None = None) -> None:
        import onnxruntime as ort

        self.path = Path(path)
        self.config = config or MonoDepthConfig()
        if not self.path.is_file():
            raise MonoDepthError(f"{self.path}: model file not found")
        opts = ort.SessionOptions()
        if self.config.threads > 0:
            opts.intra_op_num_threads = int(self.config.threads)
        opts.log_severity_level = 3
        self.providers = select_providers(self.config.device, ort.get_available_providers())
        try:
            self.session = ort.InferenceSession(str(self.path), sess_options=opts,
                                                providers=self.providers)
        except Exception as err:  # onnxruntime raises its own exception types
            first = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
            raise MonoDepthError(f"{self.path}: not a loadable ONNX model ({first})") from err
        inputs = self.session.get_inputs()
        outputs = self.session.get_outputs()
        if len(inputs) != 1:
            raise MonoDepthError(f"{self.path}: expected one image input, the model has "
                                 f"{len(inputs)} ({', '.join(i.name for i in inputs)})")
        shape = list(inputs[0].shape)
        if len(shape) != 4 or shape[1] != 3 or _dim(shape[0]) not in (None, 1):
            raise MonoDepthError(f"{self.path}: unexpected input shape {shape} of "
                                 f"'{inputs[0].name}'; expected (1, 3, H, W) (NCHW RGB)")
        if "float" not in inputs[0].type:
            raise MonoDepthError(f"{self.path}: input '{inputs[0].name}' is {inputs[0].type}; "
                                 "expected a float tensor")
        if not outputs:
            raise MonoDepthError(f"{self.path}: the model has no output")
        oshape = list(outputs[0].shape)
        if len(oshape) not in (3, 4) or (len(oshape) == 4 and _dim(oshape[1]) not in (None, 1)):
            raise MonoDepthError(f"{self.path}: unexpected output shape {oshape} of "
                                 f"'{outputs[0].name}'; expected (1, H, W) or (1, 1, H, W)")
        self.input_name = inputs[0].name
        self.output_name = outputs[0].name
        self.declared_hw = (_dim(shape[2]), _dim(shape[3]))
        log.info("%s: input %s %s, output %s, providers %s", self.path.name, self.input_name,
                 shape, oshape, self.providers)

    def input_size(self, width: int, height: int) -> tuple[int, int]:
        """``(W, H)`` the network runs at for an image of ``width x height``."""
        dh, dw = self.declared_hw
        if dh is not None and dw is not None:
            return dw, dh
        m = self.config.size_multiple
        s = self.config.dynamic_long_side_px / max(width, height)
        w = dw or max(m, round(width * s / m) * m)
        h = dh or max(m, round(height * s / m) * m)
        return w, h

    def _preprocess(self, image: np.ndarray, size: tuple[int, int]) -> F32:
        img = np.asarray(image)
        if img.ndim == 2:
            img = np.repeat(img[..., None], 3, axis=2)
        if img.ndim != 3 or img.shape[2] not in (3, 4):
            raise MonoDepthError(f"expected an (H, W) or (H, W, 3) image, got {img.shape}")
        img = img[..., :3]
        if img.dtype == np.uint8:
            x = img.astype(np.float32) / 255.0
        elif img.dtype == np.uint16:
            x = img.astype(np.float32) / 65535.0
        else:
            x = np.clip(img.astype(np.float32), 0.0, 1.0)
        x = np.asarray(cv2.resize(x, size, interpolation=cv2.INTER_AREA if size[0] <
                                  img.shape[1] else cv2.INTER_LINEAR), dtype=np.float32)
        if self.config.normalize == "imagenet":
            x = (x - _IMAGENET_MEAN) / _IMAGENET_STD
        return np.ascontiguousarray(x.transpose(2, 0, 1)[None], dtype=np.float32)

    def predict(self, image: np.ndarray) -> tuple[F32, dict[str, float]]:
        """The network's output for an RGB image, at the image's size.

        Args:
            image: ``(H, W, 3)`` RGB (or ``(H, W)`` grey), uint8, uint16 or float in [0, 1].

        Returns:
            ``(H, W)`` float32 raw output (see :attr:`MonoDepthConfig.output_kind`) and
            timings (``preprocess_s``, ``inference_s``, ``resize_s``).

        Raises:
            MonoDepthError: a bad image, or an output that is not one map.
        """
        t0 = time.perf_counter()
        h, w = np.asarray(image).shape[:2]
        size = self.input_size(w, h)
        x = self._preprocess(image, size)
        t1 = time.perf_counter()
        try:
            (y,) = self.session.run([self.output_name], {self.input_name: x})
        except Exception as err:  # onnxruntime's own exception types
            raise MonoDepthError(f"{self.path}: inference failed at input size "
                                 f"{size[0]}x{size[1]}: {err}") from err
        t2 = time.perf_counter()
        y = np.asarray(y, dtype=np.float32)
        y = y.reshape(y.shape[-2:]) if y.size == y.shape[-1] * y.shape[-2] else y
        if y.ndim != 2:
            raise MonoDepthError(f"{self.path}: output has shape {y.shape}; expected one map")
        out = cv2.resize(y, (w, h), interpolation=cv2.INTER_LINEAR)
        t3 = time.perf_counter()
        return np.asarray(out, dtype=np.float32), {
            "preprocess_s": t1 - t0, "inference_s": t2 - t1, "resize_s": t3 - t2}
