"""Printable calibration boards: a minimal PDF writer at true scale.

Checkerboards are drawn as vector squares (exact at any printer resolution); ChArUco boards and
tag grids are embedded as a 1-bit-looking grey image whose placement matrix fixes its printed
size exactly. A 100 mm scale bar and the board's spec are printed under the board so that the
scale can be checked with a ruler ("print at 100 %, no fit-to-page").
"""

from __future__ import annotations

import re
import zlib

import numpy as np

from sea3d.calib.targets import BoardSpec, board_origin_offset_m, render_board
from sea3d.errors import ConfigError

__all__ = ["PAPER_SIZES_MM", "board_pdf", "paper_size_mm"]

PT_PER_M = 72.0 / 0.0254
"""PDF points per metre (1 pt = 1/72 inch)."""

PAPER_SIZES_MM: dict[str, tuple[float, float]] = {
    "A0": (841.0, 1189.0), "A1": (594.0, 841.0), "A2": (420.0, 594.0), "A3": (297.0, 420.0),
    "A4": (210.0, 297.0), "A5": (148.0, 210.0), "letter": (215.9, 279.4),
    "legal": (215.9, 355.6), "tabloid": (279.4, 431.8),
}


def paper_size_mm(name: str) -> tuple[float, float]:
    """``(width, height)`` in mm (portrait) of a paper name (A0-A5, letter, legal, tabloid) or
    of ``WIDTHxHEIGHTmm``.

    Raises:
        ConfigError: an unknown name.
    """
    for key, size in PAPER_SIZES_MM.items():
        if key.lower() == name.strip().lower():
            return size
    m = re.fullmatch(r"\s*([0-9.]+)\s*x\s*([0-9.]+)\s*mm\s*", name, flags=re.IGNORECASE)
    if m:
        w, h = float(m.group(1)), float(m.group(2))
        if w > 0 and h > 0:
            return w, h
    raise ConfigError(f"unknown paper {name!r}; use one of {', '.join(PAPER_SIZES_MM)} or "
                      f"WIDTHxHEIGHTmm such as 1000x700mm")


def _pdf(objects: list[bytes]) -> bytes:
    """Assemble numbered objects (1-based; object 1 is the catalog) into a PDF file."""
    out = bytearray(b"%PDF-1.4\n%\xe2\xe3\xcf\xd3\n")
    offsets = []
    for i, body in enumerate(objects, start=1):
        offsets.append(len(out))
        out += f"{i} 0 obj\n".encode() + body + b"\nendobj\n"
    xref = len(out)
    out += f"xref\n0 {len(objects) + 1}\n0000000000 65535 f \n".encode()
    for off in offsets:
        out += f"{off:010d} 00000 n \n".encode()
    out += (f"trailer\n<< /Size {len(objects) + 1} /Root 1 0 R >>\nstartxref\n{xref}\n%%EOF\n"
            .encode())
    return bytes(out)


def _stream(content: bytes, extra: str = "") -> bytes:
    data = zlib.compress(content)
    return (f"<< /Length {len(data)} /Filter /FlateDecode {extra}>>\nstream\n".encode() + data
            + b"\nendstream")


def board_pdf(board: BoardSpec, paper: str = "A4", *, margin_mm: float = 10.0,
              image_px_per_module: int = 20) -> bytes:
    """A one-page PDF with ``board`` at true scale, centred on the paper.

    The page is turned to landscape when the board fits only that way. Text under the board
    gives the spec and a 100 mm scale bar (or 10 mm for small boards).

    Args:
        board: the board.
        paper: paper name or ``WxHmm`` (see :func:`paper_size_mm`).
        margin_mm: free margin the printer needs on every side.
        image_px_per_module: raster boards: pixels per marker module (resolution).

    Returns:
        The PDF file's bytes.

    Raises:
        ConfigError: the board (plus the caption) does not fit on the paper.
    """
    pw_mm, ph_mm = paper_size_mm(paper)
    bw_m, bh_m = board.size_m
    caption_mm = 18.0
    need_w, need_h = bw_m * 1e3 + 2 * margin_mm, bh_m * 1e3 + 2 * margin_mm + caption_mm
    if need_w > pw_mm or need_h > ph_mm:
        pw_mm, ph_mm = ph_mm, pw_mm
    if need_w > pw_mm or need_h > ph_mm:
        raise ConfigError(
            f"{board.name} is {bw_m * 1e3:.0f} x {bh_m * 1e3:.0f} mm and needs "
            f"{need_w:.0f} x {need_h:.0f} mm with margins; it does not fit on {paper} "
            f"({min(pw_mm, ph_mm):.0f} x {max(pw_mm, ph_mm):.0f} mm)")
    page_w, page_h = pw_mm * 1e-3 * PT_PER_M, ph_mm * 1e-3 * PT_PER_M
    bw, bh = bw_m * PT_PER_M, bh_m * PT_PER_M
    x0 = (page_w - bw) / 2
    y_top = page_h - (page_h - bh - caption_mm * 1e-3 * PT_PER_M) / 2  # top edge of the board
    ops: list[str] = []
    image_obj: bytes | None = None
    if board.kind == "checkerboard":
        s = board.square_m * PT_PER_M
        ops.append("0 g")
        for j in range(board.rows + 1):
            for i in range(board.cols + 1):
                if (i + j) % 2 == 0:
                    # PDF y runs up; board row j runs down from the top edge.
                    ops.append(f"{x0 + i * s:.4f} {y_top - (j + 1) * s:.4f} {s:.4f} {s:.4f} re f")
    else:
        if board.kind == "charuco":
            module_m = board.marker_m / 8.0
        else:
            module_m = board.marker_m / 10.0
        px_per_m = image_px_per_module / module_m
        img = render_board(board, px_per_m=px_per_m)
        h, w = img.shape
        image_obj = _stream(np.ascontiguousarray(img).tobytes(),
                            f"/Type /XObject /Subtype /Image /Width {w} /Height {h} "
                            f"/ColorSpace /DeviceGray /BitsPerComponent 8 /Interpolate false ")
        # The image is drawn into the unit square, scaled to the board's exact printed size.
        ops.append(f"q {bw:.4f} 0 0 {bh:.4f} {x0:.4f} {y_top - bh:.4f} cm /Im1 Do Q")
    bar_mm = 100.0 if bw_m >= 0.15 else 10.0
    bar = bar_mm * 1e-3 * PT_PER_M
    y_text = y_top - bh - 8 * 1e-3 * PT_PER_M
    ops.append(f"0 g {x0:.4f} {y_text:.4f} {bar:.4f} 1.5 re f")
    origin = board_origin_offset_m(board)
    text = (f"{board.name}  |  scale bar {bar_mm:g} mm  |  print at 100 %, no fit-to-page  |  "
            f"origin {origin[0] * 1e3:g} mm right, {origin[1] * 1e3:g} mm down from the "
            f"top-left edge")
    text = text.replace("\\", "\\\\").replace("(", "\\(").replace(")", "\\)")
    ops.append(f"BT /F1 8 Tf {x0:.4f} {y_text - 11:.4f} Td ({text}) Tj ET")
    content = _stream("\n".join(ops).encode("latin-1", errors="replace"))
    resources = "/Font << /F1 5 0 R >>" + (" /XObject << /Im1 6 0 R >>" if image_obj else "")
    objects = [
        b"<< /Type /Catalog /Pages 2 0 R >>",
        b"<< /Type /Pages /Kids [3 0 R] /Count 1 >>",
        (f"<< /Type /Page /Parent 2 0 R /MediaBox [0 0 {page_w:.4f} {page_h:.4f}] "
         f"/Resources << {resources} >> /Contents 4 0 R >>").encode(),
        content,
        b"<< /Type /Font /Subtype /Type1 /BaseFont /Helvetica >>",
    ]
    if image_obj is not None:
        objects.append(image_obj)
    return _pdf(objects)
