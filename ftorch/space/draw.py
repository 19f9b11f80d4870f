"""Pictures of salient points and features in the style of figures 3.9 and 3.11.

Images are drawn enlarged (OpenCV, anti-aliased) and returned as RGB uint8 arrays.
Learned features are drawn as in figures 4.7 and 4.8: each primitive where the feature is
strongest (eq. 3.14), the parts of a geometric compound joined by solid lines, the two
sub-features of a Boolean compound by a dotted line, and an id beside the reference point.
Edgels are segments of length 2*sigma along the edge (across the gradient) centred on the
point; blobs are circles and corners squares of radius sigma, each with a line from the
centre along its orientation; a texture (7.2.1, no orientation) is a dashed circle of radius
2 sigma, its window's reach, and so is a texture part of a geometric compound. A feature bounded
to a region (``Within``) is drawn where it is strongest inside the region, with the region's
outline, thin, in the feature's colour (a circle in the object frame, an ellipse in the image
frame of a non-square image).
"""
from __future__ import annotations

import math

import cv2
import numpy as np
import torch
from torch import Tensor

from ..checkpoint import write_atomic
from ..images import to_uint8
from .evaluate import bounded_by, feature_values
from .features import Feature, LocalFeature, Texture, Within
from .primitives import BLOB, CORNER, EDGEL, PartKind
from .record import ImageRecords
from .region import Region, pixel_ellipse
from .sampling import placements

EDGEL_COLOUR = (220, 40, 40)
BLOB_COLOUR = (40, 200, 60)
CORNER_COLOUR = (40, 120, 255)


def _canvas(records: ImageRecords, n: int, image: Tensor | np.ndarray, min_side: int) -> tuple[np.ndarray, float]:
    """:func:`grey_canvas` of image n of ``records``, given as its pixels in any (H, W)-sized shape."""
    height, width = (int(v) for v in records.sizes[n])
    grey = np.asarray(image.detach().cpu() if isinstance(image, Tensor) else image, dtype=np.float64)
    return grey_canvas(grey.reshape(height, width), min_side)


def _centre(x: float, y: float, zoom: float) -> tuple[float, float]:
    return (x + 0.5) * zoom - 0.5, (y + 0.5) * zoom - 0.5


def _line(canvas, a, b, colour, width=1):
    shift = 4
    p = tuple(int(round(v * 16)) for v in a)
    q = tuple(int(round(v * 16)) for v in b)
    cv2.line(canvas, p, q, colour, width, cv2.LINE_AA, shift)


def draw_marker(canvas: np.ndarray, kind: int, x: float, y: float, sigma: float, theta: float, zoom: float,
                colour=None, width: int = 1) -> None:
    """Draw one salient point or feature location onto ``canvas`` (enlarged by ``zoom``)."""
    cx, cy = _centre(x, y, zoom)
    r = sigma * zoom
    c, s = math.cos(theta), math.sin(theta)
    if kind == EDGEL:
        _line(canvas, (cx - s * r, cy + c * r), (cx + s * r, cy - c * r), colour or EDGEL_COLOUR, width)
        return
    colour = colour or (BLOB_COLOUR if kind == BLOB else CORNER_COLOUR)
    if kind == CORNER:
        corners = [(cx - r, cy - r), (cx + r, cy - r), (cx + r, cy + r), (cx - r, cy + r)]
        for a, b in zip(corners, corners[1:] + corners[:1]):
            _line(canvas, a, b, colour, width)
    else:
        cv2.circle(canvas, (int(round(cx * 16)), int(round(cy * 16))), int(round(r * 16)), colour, width, cv2.LINE_AA, 4)
    _line(canvas, (cx, cy), (cx + c * r, cy + s * r), colour, width)


def draw_salient(records: ImageRecords, n: int, image, min_side: int = 384) -> np.ndarray:
    """Figure 3.9: edgels (left panel) and texels (right panel) of image n.

    Args:
        records: the records holding image n.
        n: the image's index in ``records``.
        image: the grey image itself, tensor or array.
        min_side: the least side of each panel (a smaller image is enlarged, nearest neighbour).

    Returns:
        the two panels side by side, RGB uint8.

    Shape:
        - image: :math:`(H, W)`.
        - Output: :math:`(H', 2W' + 8, 3)`, (H', W') = (H, W) times the zoom to ``min_side``, rounded.
    """
    left, zoom = _canvas(records, n, image, min_side)
    right = left.copy()
    points = records.mask[n].nonzero()[:, 0].tolist()
    for p in points:
        kind = int(records.kind[n, p])
        values = (float(records.x[n, p]), float(records.y[n, p]), float(records.sigma[n, p]), float(records.theta[n, p]))
        draw_marker(left if kind == EDGEL else right, kind, *values, zoom)
    gap = np.full((left.shape[0], 8, 3), 255, np.uint8)
    return np.concatenate([left, gap, right], axis=1)


def save_rgb(path, picture: np.ndarray) -> None:
    """Write an RGB uint8 array as PNG (atomically)."""
    done, png = cv2.imencode(".png", cv2.cvtColor(picture, cv2.COLOR_RGB2BGR))
    if not done:
        raise ValueError(f"could not encode a picture of shape {picture.shape} for {path}")
    write_atomic(path, png.tobytes())


PALETTE = [(230, 25, 75), (60, 180, 75), (0, 130, 200), (245, 130, 48), (145, 30, 180), (70, 200, 200),
           (240, 50, 230), (128, 128, 0), (0, 0, 128), (170, 110, 40), (128, 0, 0), (0, 128, 128)]


def to_locate(feature: Feature, out: dict, regions: tuple[Region, ...] = ()) -> None:
    """Every (part, regions around it) drawn for ``feature``, with the feature to locate for it:
    the part itself, or the part bounded by those regions (where it is strongest inside them). The
    located points of those features, keyed as ``out`` is, are what a drawing's ``where`` holds."""
    if isinstance(feature, Within):
        to_locate(feature.feature, out, bounded_by(regions, feature.region))
        return
    bounded = feature
    for region in regions:
        bounded = Within(bounded, region)
    out.setdefault((feature, regions), bounded)
    for sub in feature.subfeatures():
        to_locate(sub, out, regions)


OUTLINE_LIMIT = 1 << 20  # pixels: OpenCV's fixed-point coordinates hold no more (16 * 2^20 < 2^31)


def _outline(canvas, region: Region, records: ImageRecords, n: int, zoom: float, colour) -> None:
    """A region's outline on image n, thin: none where the image has no object frame, or where it
    reaches beyond ``OUTLINE_LIMIT`` pixels (it could not be drawn exactly; the region is in the legend)."""
    ellipse = pixel_ellipse(region, records, n)
    if ellipse is None:
        return
    (cx, cy), axes = _centre(*ellipse[:2], zoom), (ellipse[2] * zoom, ellipse[3] * zoom)
    if max(abs(cx), abs(cy)) + max(axes) > OUTLINE_LIMIT:
        return
    cv2.ellipse(canvas, (round(cx * 16), round(cy * 16)), (round(axes[0] * 16), round(axes[1] * 16)), 0, 0, 360,
                colour, 1, cv2.LINE_AA, 4)


def _dotted(canvas, a, b, colour, step: float = 4.0) -> None:
    length = math.hypot(b[0] - a[0], b[1] - a[1])
    pieces = max(1, int(length / step))
    for i in range(0, pieces, 2):
        t0, t1 = i / pieces, min(1.0, (i + 1) / pieces)
        _line(canvas, (a[0] + t0 * (b[0] - a[0]), a[1] + t0 * (b[1] - a[1])),
              (a[0] + t1 * (b[0] - a[0]), a[1] + t1 * (b[1] - a[1])), colour)


def _texture_ring(canvas, x: float, y: float, sigma: float, zoom: float, colour) -> tuple[float, float]:
    """A texture's dashed circle of radius 2 sigma around (x, y); returns its centre (canvas coordinates)."""
    centre, r = _centre(x, y, zoom), 2 * sigma * zoom
    ring = [(centre[0] + r * math.cos(a), centre[1] + r * math.sin(a)) for a in np.linspace(0, 2 * math.pi, 33)]
    for a, b in zip(ring[0::2], ring[1::2]):
        _line(canvas, a, b, colour, 2)
    return centre


def _draw_located(canvas, feature: Feature, where: dict, zoom: float, colour, outline=None,
                  regions: tuple[Region, ...] = ()) -> tuple[float, float] | None:
    """Draw one feature at its located reference point (inside the ``regions`` around it); returns
    that point (canvas coordinates). ``outline(region, colour)`` draws the region of a Within."""
    if isinstance(feature, Within):
        if outline is not None:
            outline(feature.region, colour)
        return _draw_located(canvas, feature.feature, where, zoom, colour, outline, bounded_by(regions, feature.region))
    x, y, sigma, theta = where[feature, regions]
    if not math.isfinite(x):
        return None
    if isinstance(feature, Texture):
        return _texture_ring(canvas, x, y, sigma, zoom, colour)
    if isinstance(feature, LocalFeature):
        start = tuple(torch.tensor(v, dtype=torch.float64) for v in (x, y, sigma, theta))
        previous = None
        for part, state in zip(feature.parts, placements(start, feature.attitudes())):
            px, py, ps, pt = (float(v) for v in state)
            if part.kind is PartKind.TEXTURE:  # a texture part (3.5 with 7.2.1), as a texture is drawn
                _texture_ring(canvas, px, py, ps, zoom, colour)
            else:
                draw_marker(canvas, part.kind.codes[0], px, py, ps, pt, zoom, colour, 2)
            here = _centre(px, py, zoom)
            if previous is not None:
                _line(canvas, previous, here, colour, 1)
            previous = here
        return _centre(x, y, zoom)
    drawn = [at for at in (_draw_located(canvas, sub, where, zoom, colour, outline, regions)
                           for sub in feature.subfeatures()) if at is not None]
    for a, b in zip(drawn, drawn[1:]):
        _dotted(canvas, a, b, colour)
    return drawn[0] if drawn else None


LEGEND_KEY = ("circle: blob, square: corner", "segment: edgel (sizes: sigma)", "dashed circle: texture (2 sigma)",
              "line: geometric parts, dots: and/or")


def feature_legend(features, ids, width: int) -> np.ndarray:
    """A white strip, ``width`` pixels wide: the marker key, then each feature's id and type in its colour."""
    lines = [(key, (90, 90, 90)) for key in LEGEND_KEY] + [(f"{i}: {f.describe()}", PALETTE[k % len(PALETTE)])
                                           for k, (f, i) in enumerate(zip(features, ids))]
    scale = 0.36
    strip = np.full((8 + 14 * len(lines), width, 3), 255, np.uint8)
    for row, (text, colour) in enumerate(lines):
        while len(text) > 8 and cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)[0][0] > width - 8:
            text = text[: len(text) - 4] + "..."
        cv2.putText(strip, text, (4, 16 + 14 * row), cv2.FONT_HERSHEY_SIMPLEX, scale, colour, 1, cv2.LINE_AA)
    return strip


def draw_features(records: ImageRecords, n: int, image, features, ids=None, min_side: int = 256,
                  legend: bool = False) -> np.ndarray:
    """Figures 4.7/4.8: ``features`` located in image n (eq. 3.14) and drawn with their ``ids``.

    Args:
        records: the records holding image n.
        n: the image's index in ``records``.
        image: the grey image itself, tensor or array.
        features: the features to draw.
        ids: their names in the drawing (default 0, 1, ...).
        min_side: the least side of the drawing.
        legend: with :func:`feature_legend` below.

    Returns:
        the drawing, RGB uint8.

    Shape:
        - image: :math:`(H, W)`.
        - Output: :math:`(H', W', 3)`, (H', W') = (H, W) times the zoom to ``min_side``, rounded;
          the legend adds rows.
    """
    canvas, zoom = _canvas(records, n, image, min_side)
    features = list(features)
    every: dict = {}
    for f in features:
        to_locate(f, every)
    where = {}
    if every:
        found = feature_values(list(every.values()), records[n])
        for j, key in enumerate(every):
            where[key] = tuple(float(t[j, 0]) for t in (found.x, found.y, found.sigma, found.theta))

    def outline(region: Region, colour) -> None:
        _outline(canvas, region, records, n, zoom, colour)
    for k, f in enumerate(features):
        colour = PALETTE[k % len(PALETTE)]
        point = _draw_located(canvas, f, where, zoom, colour, outline)
        if point is not None and ids is not None:
            cv2.putText(canvas, str(ids[k]), (int(point[0]) + 4, int(point[1]) - 4), cv2.FONT_HERSHEY_SIMPLEX, 0.45,
                        colour, 1, cv2.LINE_AA)
    if legend:
        canvas = np.concatenate([canvas, feature_legend(features, ids or range(1, len(features) + 1), canvas.shape[1])])
    return canvas


def titled(picture: np.ndarray, title: str) -> np.ndarray:
    """A white strip with ``title`` above an RGB picture."""
    strip = np.full((22, picture.shape[1], 3), 255, np.uint8)
    cv2.putText(strip, title, (4, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    return np.concatenate([strip, picture], axis=0)


def panel(image: Tensor, title: str, least: int = 96) -> np.ndarray:
    """A grey image in [0, 1] as a titled panel.

    Args:
        image: the grey image.
        title: the text above it.
        least: the least side: a smaller image is enlarged by pixel repetition.

    Returns:
        the panel, RGB uint8.

    Shape:
        - image: :math:`(H, W)`.
        - Output: :math:`(22 + kH, kW, 3)`, k the repetition to ``least``.
    """
    grey = to_uint8(image)
    grey = np.kron(grey, np.ones((-(-least // grey.shape[0]),) * 2, np.uint8))
    return titled(np.repeat(grey[..., None], 3, axis=2), title)


def grid(pictures: list[np.ndarray], columns: int, gap: int = 6) -> np.ndarray:
    """Equal-sized RGB pictures in a grid of ``columns`` on white."""
    height, width = max(p.shape[0] for p in pictures), max(p.shape[1] for p in pictures)
    rows = math.ceil(len(pictures) / columns)
    out = np.full((rows * (height + gap) - gap, columns * (width + gap) - gap, 3), 255, np.uint8)
    for i, p in enumerate(pictures):
        r, c = divmod(i, columns)
        out[r * (height + gap): r * (height + gap) + p.shape[0], c * (width + gap): c * (width + gap) + p.shape[1]] = p
    return out


# -- a recognition's trace (ftorch.recognition.explain): located features numbered and coloured, legend, title

TRACE_LEGEND = 600  # the width of the trace's legend column, pixels


def grey_canvas(image, min_side: int) -> tuple[np.ndarray, float]:
    """A grey (H, W) image (tensor or array) stretched to its range, faded and enlarged by pixel
    repetition to at least ``min_side`` pixels a side, as RGB uint8; and the zoom: the background
    :func:`draw_features` draws on, for one image without its records."""
    grey = np.asarray(image.detach().cpu() if isinstance(image, Tensor) else image, dtype=np.float64)
    lo, hi = float(grey.min()), float(grey.max())
    grey = (grey - lo) / (hi - lo) if hi > lo else np.zeros_like(grey)
    height, width = grey.shape
    zoom = max(1.0, min_side / min(height, width))
    big = cv2.resize((grey * 255).astype(np.uint8), (round(width * zoom), round(height * zoom)), interpolation=cv2.INTER_NEAREST)
    faded = (0.55 * big + 0.45 * 255).astype(np.uint8)
    return cv2.cvtColor(faded, cv2.COLOR_GRAY2RGB), zoom


def text_strip(lines, width: int, scale: float = 0.36, pitch: int = 14) -> np.ndarray:
    """A white strip ``width`` pixels wide holding ``lines`` of (text, colour), each wrapped at spaces
    to the width (continuations indented)."""
    rows = []
    for text, colour in lines:
        words, row = text.split(" "), ""
        for word in words:
            longer = f"{row} {word}" if row else word
            if row and cv2.getTextSize(longer, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)[0][0] > width - 8:
                rows.append((row, colour))
                row = "   " + word
            else:
                row = longer
        rows.append((row, colour))
    strip = np.full((pitch // 2 + pitch * len(rows), width, 3), 255, np.uint8)
    for n, (text, colour) in enumerate(rows):
        cv2.putText(strip, text, (4, pitch + pitch * n - 2), cv2.FONT_HERSHEY_SIMPLEX, scale, colour, 1, cv2.LINE_AA)
    return strip


def draw_trace(image, marks, lines, title: str, min_side: int = 384) -> np.ndarray:
    """One image with located features drawn on it, RGB uint8: ``marks`` are (feature, where, colour,
    label), ``where`` mapping the feature and its sub-features to (x, y, sigma, theta) as
    :func:`~ftorch.space.evaluate.feature_values` locates them (NaN: not drawn); each is drawn as
    :func:`draw_features` draws it, ``label`` beside its reference point. Right of the image the
    marker key and ``lines`` of (text, colour); ``title`` above both."""
    canvas, zoom = grey_canvas(image, min_side)
    for feature, where, colour, label in marks:
        point = _draw_located(canvas, feature, where, zoom, colour)
        if point is not None and label:
            at = (int(point[0]) + 4, int(point[1]) - 4)
            cv2.putText(canvas, label, at, cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 3, cv2.LINE_AA)
            cv2.putText(canvas, label, at, cv2.FONT_HERSHEY_SIMPLEX, 0.5, colour, 1, cv2.LINE_AA)
    legend = text_strip([(key, (90, 90, 90)) for key in LEGEND_KEY] + list(lines), TRACE_LEGEND)
    height = max(canvas.shape[0], legend.shape[0])
    body = np.full((height, canvas.shape[1] + 8 + TRACE_LEGEND, 3), 255, np.uint8)
    body[:canvas.shape[0], :canvas.shape[1]] = canvas
    body[:legend.shape[0], canvas.shape[1] + 8:] = legend
    head = text_strip([(title, (0, 0, 0))], body.shape[1], scale=0.5, pitch=20)
    return np.concatenate([head, body], axis=0)
