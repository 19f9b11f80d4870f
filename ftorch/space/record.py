"""Image records: everything about an image that features need, computed once (DESIGN.md data flow).

An :class:`ImageRecords` holds a batch of images, padded to common sizes with masks:
the response pyramid (for sampling at arbitrary x, y, sigma), the salient points and their
primitive descriptors. Every descriptor has the 15-slot texel layout
[basis @ level-1 | basis @ level | basis @ level+1] (3.4.2); an edgel fills only the two
first-order slots of the middle block (3.4.1) and leaves the rest zero.
"""
from __future__ import annotations

import functools
import os
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Sequence

import numpy as np
import torch
from torch import Tensor, nn
from tqdm import tqdm

from ..errors import InputError
from ..images import as_image, as_image_batch, contrast_normalized
from .primitives import BLOB, CORNER, DESCRIPTOR, EDGEL, EDGEL_SLOTS, PartKind
from .salient import Points, SalientPoints
from .scale_space import PLANS, ScaleSpace, ScaleSpaceOutput
from .steering import steer
from .texture import TextureGrid


def kind_slots(kind: Tensor) -> Tensor:
    """(…, 15) bool mask of the descriptor slots a primitive of ``kind`` uses."""
    slots = torch.ones(*kind.shape, DESCRIPTOR, dtype=torch.bool, device=kind.device)
    edgel_slots = torch.zeros(DESCRIPTOR, dtype=torch.bool, device=kind.device)
    edgel_slots[EDGEL_SLOTS] = True
    return torch.where((kind == EDGEL)[..., None], edgel_slots, slots)


class ResponsePyramids:
    """The response pyramids of a batch of images, stored once in the layout sampling reads.

    ``first`` (N, H, W, S+3, 2) and ``second`` (N, H, W, S+3, 3) hold at [n, y, x, j] the first-
    and second-order basis responses of level j-1 (zero outside the pyramid), so the levels around
    any pixel and level are one contiguous run of each that sampling reads as a row
    (``ftorch.space.sampling``): an edgel reads 4 numbers of ``first``, a texel 8 and 12. Record batches
    selected from one another share their :class:`ResponsePyramids` (no copies).
    """

    def __init__(self, first: Tensor, second: Tensor):
        self.first, self.second = first, second

    @classmethod
    def of(cls, responses: Tensor) -> "ResponsePyramids":
        """The pyramid of responses (N, S, 5, H, W)."""
        batch, levels, _, height, width = responses.shape
        out = cls.zeros(batch, height, width, levels + 3, responses.dtype, responses.device)
        out.write(0, responses)
        return out

    def write(self, start: int, responses: Tensor) -> None:
        """Responses (n, S, 5, H, W) into images start, start+1, ... (top left; level j at entry j+1)."""
        n, levels, _, height, width = responses.shape
        at = (slice(start, start + n), slice(0, height), slice(0, width), slice(1, levels + 1))
        self.first[at] = responses[:, :, :2].permute(0, 3, 4, 1, 2)
        self.second[at] = responses[:, :, 2:].permute(0, 3, 4, 1, 2)

    def __len__(self) -> int:
        return self.first.shape[0]

    @property
    def responses(self) -> Tensor:
        """(N, S, 5, H, W), a copy."""
        return torch.cat([self.first, self.second], -1)[:, :, :, 1:-2].permute(0, 3, 4, 1, 2)

    def to(self, device) -> "ResponsePyramids":
        return ResponsePyramids(self.first.to(device), self.second.to(device))

    @staticmethod
    def cat(pyramids: Sequence["ResponsePyramids"]) -> "ResponsePyramids":
        """One pyramid of several, padded with zeros to the largest height, width and level count."""
        dtype = functools.reduce(torch.promote_types, [p.first.dtype for p in pyramids])
        height, width, entries = (max(p.first.shape[d] for p in pyramids) for d in (1, 2, 3))
        out = ResponsePyramids.zeros(sum(len(p) for p in pyramids), height, width, entries, dtype, pyramids[0].first.device)
        start = 0
        for p in pyramids:
            out.put(start, p)
            start += len(p)
        return out

    @staticmethod
    def zeros(n: int, height: int, width: int, entries: int, dtype: torch.dtype, device) -> "ResponsePyramids":
        """An empty pyramid of n images of ``entries`` = S+3 table entries."""
        return ResponsePyramids(*(torch.zeros(n, height, width, entries, k, dtype=dtype, device=device) for k in (2, 3)))

    def put(self, start: int, other: "ResponsePyramids") -> None:
        """Copy ``other`` into images start, start+1, ... (top left; the rest stays zero)."""
        _, height, width, entries, _ = other.first.shape
        rows = slice(start, start + len(other))
        self.first[rows, :height, :width, :entries] = other.first
        self.second[rows, :height, :width, :entries] = other.second


@dataclass
class ImageRecords:
    """A padded batch of N image records.

    pyramid: the response pyramids, shared by batches selected from one another, and source (N,)
    each record's row in it; levels (N,) and sizes (N, 2) = (H, W) per image;
    per point (N, P): x, y (pixels; x = column), level, sigma, theta, kind, strength, mask;
    descriptors (N, P, 15) in the image frame and canonical (N, P, 15) steered to theta;
    per texture grid point (N, Q): grid_x, grid_y, grid_level, grid_mask, and the square-rooted
    intensity histograms (N, Q, BINS) there (``ftorch.space.texture``, 7.2.1).
    """

    pyramid: ResponsePyramids
    source: Tensor
    levels: Tensor
    sizes: Tensor
    x: Tensor
    y: Tensor
    level: Tensor
    sigma: Tensor
    theta: Tensor
    kind: Tensor
    strength: Tensor
    mask: Tensor
    descriptors: Tensor
    canonical: Tensor
    grid_x: Tensor
    grid_y: Tensor
    grid_level: Tensor
    grid_mask: Tensor
    histograms: Tensor

    def __post_init__(self) -> None:
        # the reference points of each part kind or texture level, found once per records object
        # by the feature values (ftorch/space/evaluate.py), and the images' object frames
        # (ftorch/space/region.py); records are never changed in place
        self.reference_points: dict = {}

    @classmethod
    def build(cls, space: ScaleSpaceOutput, points: Points, texture: tuple[Tensor, ...], into: ResponsePyramids | None = None,
              offset: int = 0) -> "ImageRecords":
        """Records of one batch (``texture``: its :class:`~ftorch.space.texture.TextureGrid`); its
        pyramid is written into images offset, ... of ``into`` where given."""
        responses = space.responses
        batch, levels, _, height, width = responses.shape
        b, y, x, k = points.image, points.y, points.x, points.level
        lower = (k - 1).clamp(min=0)
        upper = (k + 1).clamp(max=levels - 1)
        blocks = torch.stack([responses[b, lower, :, y, x], responses[b, k, :, y, x], responses[b, upper, :, y, x]], 1)
        raw = blocks.flatten(1) * kind_slots(points.kind)
        counts = torch.bincount(b, minlength=batch)
        width_p = int(counts.max()) if len(b) else 0
        start = torch.cumsum(counts, 0) - counts
        slot = torch.arange(len(b), device=b.device) - start[b]

        def pad(values: Tensor, fill=0) -> Tensor:
            out = torch.full((batch, width_p, *values.shape[1:]), fill, dtype=values.dtype, device=values.device)
            out[b, slot] = values
            return out

        dtype = responses.dtype
        level_sigma = 2.0 ** (k.to(dtype) / 2)
        if into is not None:
            into.write(offset, responses)
        return cls(
            pyramid=ResponsePyramids.of(responses) if into is None else into,
            source=torch.arange(offset, offset + batch, device=responses.device),
            levels=torch.full((batch,), levels, dtype=torch.long, device=responses.device),
            sizes=torch.tensor([[height, width]] * batch, dtype=torch.long, device=responses.device),
            x=pad(x.to(dtype)),
            y=pad(y.to(dtype)),
            level=pad(k),
            sigma=pad(level_sigma, 1),
            theta=pad(points.theta),
            kind=pad(points.kind, -1),
            strength=pad(points.strength),
            mask=pad(torch.ones_like(b, dtype=torch.bool), False),
            descriptors=pad(raw),
            canonical=pad(steer(raw, points.theta)),
            grid_x=texture[0].expand(batch, -1),
            grid_y=texture[1].expand(batch, -1),
            grid_level=texture[2].expand(batch, -1),
            grid_mask=torch.ones(batch, len(texture[0]), dtype=torch.bool, device=responses.device),
            histograms=texture[3],
        )

    def own_pyramid(self) -> ResponsePyramids:
        """The pyramid of exactly these records, in their order (shared where it is the whole one)."""
        whole = self.pyramid
        if len(self) == len(whole) and bool((self.source == torch.arange(len(self), device=self.device)).all()):
            return whole
        return ResponsePyramids(whole.first[self.source], whole.second[self.source])

    @property
    def responses(self) -> Tensor:
        """(N, S, 5, H, W) responses of these records (a copy)."""
        return self.own_pyramid().responses

    @property
    def dtype(self) -> torch.dtype:
        return self.pyramid.first.dtype

    @property
    def nbytes(self) -> int:
        """Bytes held: the whole shared pyramid and these records' points and descriptors."""
        return self.pyramid.first.nbytes + self.pyramid.second.nbytes + sum(
            getattr(self, f.name).nbytes for f in fields(self)[1:])

    def __len__(self) -> int:
        return self.source.shape[0]

    def __getitem__(self, index) -> "ImageRecords":
        """The records ``index`` selects (an int, slice or index tensor); the pyramid is shared."""
        if isinstance(index, int):
            if len(self) == 1 and index in (0, -1):
                return self  # one record selecting itself: keeps what was computed for it (feature values' points)
            index = slice(index, index + 1) if index != -1 else slice(-1, None)
        return ImageRecords(self.pyramid, **{f.name: getattr(self, f.name)[index] for f in fields(self)[1:]})

    def to(self, device) -> "ImageRecords":
        return ImageRecords(self.pyramid.to(device), **{f.name: getattr(self, f.name).to(device) for f in fields(self)[1:]})

    @property
    def device(self) -> torch.device:
        return self.source.device

    def texel_mask(self) -> Tensor:
        return PartKind.TEXEL.mask(self)

    def edgel_mask(self) -> Tensor:
        return PartKind.EDGEL.mask(self)

    def counts(self) -> dict[str, list[int]]:
        """Numbers of edgels, blobs and corners per image."""
        return {
            "edgels": self.edgel_mask().sum(1).tolist(),
            "blobs": (self.mask & (self.kind == BLOB)).sum(1).tolist(),
            "corners": (self.mask & (self.kind == CORNER)).sum(1).tolist(),
        }

    @staticmethod
    def cat(records: Sequence["ImageRecords"], pyramid: ResponsePyramids | None = None) -> "ImageRecords":
        """Concatenate records of different sizes, padding pyramids and point lists; ``pyramid``:
        the joined pyramid, in this order, where the caller has built it (their own are not read)."""
        if len(records) == 1 and pyramid is None:
            return records[0]
        fills = {"sigma": 1, "kind": -1, "mask": False, "grid_level": -1, "grid_mask": False}
        joined = {}
        for f in fields(ImageRecords)[2:]:
            parts = [getattr(r, f.name) for r in records]
            if f.name in ("levels", "sizes"):
                joined[f.name] = torch.cat(parts)
                continue
            shape = [max(p.shape[d] for p in parts) for d in range(1, parts[0].ndim)]
            joined[f.name] = torch.cat([_pad(p, shape, fills.get(f.name, 0)) for p in parts])
        pyramid = ResponsePyramids.cat([r.own_pyramid() for r in records]) if pyramid is None else pyramid
        return ImageRecords(pyramid, torch.arange(len(pyramid), device=pyramid.first.device), **joined)


def _pad(t: Tensor, shape: list[int], fill) -> Tensor:
    if list(t.shape[1:]) == shape:
        return t
    out = torch.full((t.shape[0], *shape), fill, dtype=t.dtype, device=t.device)
    out[tuple([slice(None)] + [slice(0, s) for s in t.shape[1:]])] = t
    return out


class FeatureSpace(nn.Module):
    """Images -> :class:`ImageRecords` (scale space, salient points, descriptors).

    ``forward`` takes one batch of equal-sized images; :meth:`records` takes any sequence of
    images, arrays or file paths of mixed sizes and returns them as one padded batch in order.

    Args:
        truncate: kernel radius in sigmas (:class:`~ftorch.space.scale_space.ScaleSpace`).
        rel_threshold: the salient points' relative threshold (:class:`~ftorch.space.salient.SalientPoints`).

    Shape:
        - Input: :math:`(B, C, H, W)` (C = 1 grey or 3 RGB), :math:`(B, H, W)` or :math:`(H, W)`.
        - Output: :class:`ImageRecords` of B images, per point :math:`(B, P)` (P the most points of
          any image), descriptors :math:`(B, P, 15)`, per texture grid point :math:`(B, Q)`.
    """

    def __init__(self, truncate: float = 3.0, rel_threshold: float = 1e-2):
        super().__init__()
        self.scale_space = ScaleSpace(truncate)
        self.salient = SalientPoints(rel_threshold)
        self.texture = TextureGrid(truncate)

    def get_extra_state(self) -> dict:
        """The settings the kernels and thresholds are made from: what ``state_dict`` holds (the
        kernels themselves are derived buffers, not state)."""
        return {"truncate": self.scale_space.truncate, "rel_threshold": self.salient.rel_threshold}

    def set_extra_state(self, state: dict) -> None:
        """Rebuild the parts from settings written by :meth:`get_extra_state`, on this module's device."""
        device = next(iter(self.scale_space.buffers())).device
        self.scale_space = ScaleSpace(state["truncate"]).to(device)
        self.salient = SalientPoints(state["rel_threshold"])
        self.texture = TextureGrid(state["truncate"])  # plans are built per device when used

    def forward(self, images) -> ImageRecords:
        images = as_image_batch(images)
        space = self.scale_space(contrast_normalized(images))  # invariant to I -> a*I + b (3.4.4)
        return ImageRecords.build(space, self.salient(space), self._texture(images, space))

    def _texture(self, images: Tensor, space: ScaleSpaceOutput) -> tuple[Tensor, ...]:
        return self.texture(images[:, 0].to(space.responses.dtype), space.responses.shape[1])

    def _pyramid_layout(self, shapes: Sequence[tuple[int, ...]]) -> tuple[int, int, int]:
        """(height, width, S+3 entries) of the joined pyramid of images of these (H, W) shapes."""
        height, width = (max(shape[d] for shape in shapes) for d in (0, 1))
        return height, width, max(self.scale_space.num_levels(*shape) for shape in shapes) + 3

    def pyramid_nbytes(self, images: Sequence) -> int:
        """Bytes of the pyramid :meth:`records` builds for these grey (H, W) float images (or for
        float32 images of these (H, W) shapes), known before building it: a lower bound of the
        records' ``nbytes`` (points and descriptors add to it)."""
        shapes = [tuple(image.shape[-2:]) if isinstance(image, Tensor) else tuple(image) for image in images]
        height, width, entries = self._pyramid_layout(shapes)
        dtype = functools.reduce(torch.promote_types, [image.dtype if isinstance(image, Tensor) else torch.float32
                                                       for image in images])
        return len(images) * height * width * entries * 5 * dtype.itemsize  # 2 first- and 3 second-order maps

    def matrices_nbytes(self, images: Sequence) -> int:
        """Bytes of the filter matrices :meth:`records` builds and caches for these images (or float32
        images of these (H, W) shapes): one scale-space and one texture plan per size and dtype, at
        most the ``PLANS`` largest at once (the caches' size); an upper bound known before building them."""
        keys = {(tuple(image.shape[-2:]), image.dtype) if isinstance(image, Tensor) else (tuple(image), torch.float32)
                for image in images}
        sizes = sorted(self.scale_space.plan_nbytes(height, width, dtype)
                       + self.texture.plan_nbytes(height, width, self.scale_space.num_levels(height, width), dtype)
                       for (height, width), dtype in keys)
        return sum(sizes[-PLANS:])

    def _loaded(self, item, name: str | None, i: int, device: torch.device) -> torch.Tensor:
        """Image ``i`` as a (1, H, W) tensor on ``device``; InputError naming it (``name``, else its file
        path or images[i]) where it is no image or too small for the scale space."""
        name = name if name is not None else str(item) if isinstance(item, (str, Path)) else f"images[{i}]"
        image = as_image(item, name)
        try:
            self.scale_space.num_levels(*image.shape)
        except InputError as err:
            raise InputError(f"{name}: {err}") from None
        return image[None].to(device)

    def records(self, images: Sequence, batch_size: int = 16, progress: bool = False,
                names: Sequence[str] | None = None) -> ImageRecords:
        """Records of images of any sizes, computed in batches of one size and joined in order.

        Args:
            images: files, arrays or tensors, each one image (``ftorch.images.as_image``), or one
                array of several.
            batch_size: the most images computed at once.
            progress: show a progress bar.
            names: the images' names in errors (default: the file path, or images[i]).

        Returns:
            the records of all images, padded to the largest size and point count.

        Shape:
            - images: N images, each of its own :math:`(H_i, W_i)`, grey or colour (``as_image``'s rules).
            - Output: :class:`ImageRecords` of N images.
        """
        if isinstance(images, (np.ndarray, torch.Tensor)):  # one array: its images, by the rules of as_image_batch
            images = list(as_image_batch(images))
        if len(images) == 0:
            raise InputError("images: the sequence is empty")
        device = next(iter(self.scale_space.buffers())).device
        loaded = [self._loaded(item, names[i] if names is not None else None, i, device) for i, item in enumerate(images)]
        height, width, entries = self._pyramid_layout([image.shape[-2:] for image in loaded])
        require_memory(self.pyramid_nbytes(loaded), device, f"{len(loaded)} images of up to {height}x{width} pixels",
                       self.matrices_nbytes(loaded))
        groups: dict[tuple, list[int]] = {}
        for i, image in enumerate(loaded):
            groups.setdefault((tuple(image.shape), image.dtype), []).append(i)
        chunks = [(key, idx[s : s + batch_size]) for key, idx in groups.items() for s in range(0, len(idx), batch_size)]
        # each batch's responses are written straight into the joined pyramid, so that building
        # holds one set of tables, not two
        parts: list[ImageRecords] = []
        order: list[int] = []
        pyramid: ResponsePyramids | None = None
        for _, idx in tqdm(chunks, desc="image records", unit="batch", disable=not progress):
            batch = torch.stack([loaded[i] for i in idx])
            space = self.scale_space(contrast_normalized(batch))
            if pyramid is None:
                dtype = functools.reduce(torch.promote_types, [space.responses.dtype] + [image.dtype for image in loaded])
                pyramid = ResponsePyramids.zeros(len(loaded), height, width, entries, dtype, device)
            parts.append(ImageRecords.build(space, self.salient(space), self._texture(batch, space), pyramid, len(order)))
            order.extend(idx)
        joined = ImageRecords.cat(parts, pyramid)
        inverse = torch.empty(len(order), dtype=torch.long)
        inverse[torch.tensor(order)] = torch.arange(len(order))
        return joined[inverse.to(joined.device)]


def free_memory(device: torch.device) -> int | None:
    """Bytes free for new tensors on ``device``: the GPU's free memory, or the CPU's available memory
    (Linux's MemAvailable, else the free physical pages); None where the system does not tell."""
    device = torch.device(device)
    if device.type == "cuda":
        return int(torch.cuda.mem_get_info(device)[0])
    if device.type != "cpu":
        return None
    try:
        with open("/proc/meminfo", encoding="ascii") as info:
            for line in info:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def require_memory(nbytes: int, device, what: str, matrices: int = 0) -> None:
    """InputError, before anything is computed, where ``what`` needs a scale-space pyramid of
    ``nbytes`` and filter matrices of ``matrices`` bytes that ``device`` has no room for (:func:`free_memory`)."""
    free = free_memory(device)
    if free is not None and nbytes + matrices > free:
        also = f" and {matrices / 2**30:.1f} GiB for its filter matrices" if matrices else ""
        raise InputError(f"{what} need {nbytes / 2**30:.1f} GiB for their scale-space pyramid{also}, more than the "
                         f"{free / 2**30:.1f} GiB free on {torch.device(device)}: reduce the images (area averaging "
                         "to a smaller side, e.g. the runner's --size) or use fewer at once")
