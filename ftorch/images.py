"""Turning user images into the (B, 1, H, W) float batches every ftorch module takes.

Rules:
- torch tensors and numpy arrays; shape (H, W), (B, H, W) or (B, C, H, W) with C = 1 or 3.
- uint8 is divided by 255, uint16 by 65535; float16/bfloat16 become float32; float32 and
  float64 are kept as they are (values need not lie in [0, 1]: texels, edgels and their
  compounds are invariant to I -> a*I + b, a > 0, by :func:`contrast_normalized`; the texture
  primitive reads intensities in [0, 1] as given). Other dtypes are refused, and so is an image
  whose values cannot hold its contrast (:data:`MIN_LEVELS`).
- Colour (C = 3, RGB order) becomes grey by ITU-R BT.601 luma, 0.299 R + 0.587 G + 0.114 B.
  Files are read with OpenCV (BGR order, handled) and converted by the same rule.
- A 3-D array or tensor whose last axis has 1, 3 or 4 entries is one image (H, W, C): grey, RGB
  or RGBA, as PIL and matplotlib give it (alpha is dropped): read as a batch it would be
  images 3 or 4 pixels wide, far below the smallest the scale space takes. Arrays from
  ``cv2.imread`` are BGR: pass the file itself, or convert with ``cv2.cvtColor(a, cv2.COLOR_BGR2RGB)``.
- Where one image is expected (:func:`as_image`: an entry of a list of images), a 3-D array whose
  first axis has 1 or 3 entries and whose last has not is in torch's (C, H, W) order; anything
  that holds more than one image is refused, never cut to its first slice or channel.
- Tensors must hold pixels: on the CPU or a CUDA device (not the meta device).
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import torch
from torch import Tensor

from .errors import InputError

LUMA = (0.299, 0.587, 0.114)
# steps of its dtype a float image's range must span (:func:`_check_contrast`): 2^15, what float32 holds across one
# grey level of an 8-bit image at its brightest, so every 8-bit image in [0, 1] passes; answers were seen to change
# below 2.5e3 steps and never from 5e3 on (docs/decisions.md, "Contrast")
MIN_LEVELS = 2**15


def to_uint8(image: Tensor) -> np.ndarray:
    """A grey (H, W) image in [0, 1] as 8-bit pixels, clipped and rounded (for PNGs and OpenCV)."""
    return (image.detach().cpu().clamp(0, 1).numpy() * 255).round().astype(np.uint8)


def as_image_batch(images, name: str = "images") -> Tensor:
    """Validate and convert ``images`` to a finite float batch (B, 1, H, W)."""
    if isinstance(images, np.ndarray):
        if images.dtype == object:
            raise InputError(f"{name}: numpy array of dtype object is not an image")
        images = torch.from_numpy(np.ascontiguousarray(images))
    if not isinstance(images, Tensor):
        raise InputError(f"{name}: expected a torch.Tensor or numpy array, got {type(images).__name__}")
    if images.device.type not in ("cpu", "cuda"):
        raise InputError(f"{name}: a tensor on the {images.device.type} device holds no pixels to read; "
                         "expected one on the CPU or a CUDA device")
    shape = tuple(images.shape)
    if images.numel() == 0:
        raise InputError(f"{name}: empty image, shape {shape}")
    if images.ndim == 2:
        images = images[None, None]
    elif images.ndim == 3 and images.shape[-1] in (1, 3, 4):
        images = images[..., :3].permute(2, 0, 1)[None]  # one (H, W, C) image, see the rules
    elif images.ndim == 3:
        images = images[:, None]
    elif images.ndim != 4:
        raise InputError(f"{name}: expected shape (H, W), (B, H, W) or (B, C, H, W), got {shape}")
    if images.shape[1] not in (1, 3):
        raise InputError(f"{name}: expected 1 (grey) or 3 (RGB) channels on dim 1, got shape {shape}")
    given = images.dtype
    images = _to_float(images, name)
    if images.shape[1] == 3:
        weights = torch.tensor(LUMA, dtype=images.dtype, device=images.device)
        images = (images * weights[None, :, None, None]).sum(1, keepdim=True)
    finite = torch.isfinite(images)
    if not bool(finite.all()):
        bad = int((~finite).sum())
        raise InputError(f"{name}: {bad} of {images.numel()} pixels are NaN or infinite")
    _check_contrast(images, name, given)
    return images


def contrast_normalized(images: Tensor) -> Tensor:
    """Images (..., H, W) with each one's contrast brought into (1/2, 1] exactly, so that what is
    salient (an absolute floor on the responses, :mod:`ftorch.space.salient`) and every response
    are the same for I and a*I + b (3.4.4), and no square of a response overflows or underflows
    (what :class:`~ftorch.space.record.FeatureSpace` measures; the scale space itself, as a filter
    bank, responds to the image as given).

    Each image is multiplied by the power of two that brings its range (max - min) into (1/2, 1]:
    an exact operation, so an image whose range lies there already (every 8-bit image that uses
    more than half its grey levels) is used bit for bit as given. An offset larger than the range
    (|min| > max - min) is subtracted first, as it would cost precision in every filter sum; a
    smaller one costs less than a bit and is kept. A flat image stays flat (zero)."""
    with torch.no_grad():
        low, high = images.amin((-2, -1), keepdim=True), images.amax((-2, -1), keepdim=True)
        span = high - low
        offset = torch.where(low.abs() > span, low, torch.zeros_like(low))
        mantissa, exponent = torch.frexp(span)  # span = mantissa * 2^exponent, mantissa in [1/2, 1)
        exponent = torch.where(mantissa == 0.5, exponent - 1, exponent)  # a power of two: range exactly 1
        scale = torch.where(span > 0, torch.ldexp(torch.ones_like(span), -exponent), torch.ones_like(span))
    return (images - offset) * scale


def _check_contrast(images: Tensor, name: str, dtype: torch.dtype) -> None:
    """InputError where a float image's values cannot hold its contrast: its range (max - min) spans
    fewer than :data:`MIN_LEVELS` steps of its ``dtype`` at the image's magnitude (a float32 image
    of contrast 1 offset by 1e5 holds values 1/128 apart), or is not finite. Integer images are
    exact by construction and not checked."""
    if not dtype.is_floating_point:
        return
    info = torch.finfo(dtype)
    low, high = images.amin((-2, -1)).flatten().double(), images.amax((-2, -1)).flatten().double()
    span, magnitude = high - low, torch.maximum(low.abs(), high.abs())
    step = info.eps * torch.exp2(torch.floor(torch.log2(magnitude.clamp_min(info.smallest_normal))))
    levels = span / step
    bad = (~torch.isfinite(span) | ((span > 0) & (levels < MIN_LEVELS))).nonzero()
    if len(bad):
        i = int(bad[0])
        where = f"{name}[{i}]" if len(low) > 1 else name
        if not torch.isfinite(span[i]):
            raise InputError(f"{where}: its values ({float(low[i]):.3g} to {float(high[i]):.3g}) span more than "
                             f"{dtype} holds; scale it down")
        raise InputError(f"{where}: its values ({float(low[i]):.7g} to {float(high[i]):.7g}, {dtype}) lie only "
                         f"{float(levels[i]):.0f} steps of the dtype apart, fewer than the {MIN_LEVELS} that hold an "
                         "image's contrast: its offset swamps it (subtract the offset before converting, or use float64)")


def as_image(item, name: str = "image") -> Tensor:
    """One image (a file path, array or tensor) as a finite grey float (H, W) tensor, by the rules
    above; InputError where ``item`` holds more than one image."""
    if isinstance(item, (str, Path)):
        return load_image(item)
    data = torch.from_numpy(np.ascontiguousarray(item)) if isinstance(item, np.ndarray) and item.dtype != object else item
    if isinstance(data, Tensor) and data.ndim == 3 and data.shape[0] in (1, 3) and data.shape[-1] not in (1, 3, 4):
        data = data[None]  # (C, H, W): one grey or RGB image in torch's order
    batch = as_image_batch(data, name)
    if batch.shape[0] != 1:
        raise InputError(f"{name}: expected one image, got shape {tuple(data.shape)}, which holds {batch.shape[0]}")
    return batch[0, 0]


def _to_float(images: Tensor, name: str) -> Tensor:
    if images.dtype == torch.uint8:
        return images.float() / 255.0
    if images.dtype == torch.uint16:
        return images.float() / 65535.0
    if images.dtype in (torch.float16, torch.bfloat16):
        return images.float()
    if images.dtype in (torch.float32, torch.float64):
        return images
    raise InputError(f"{name}: dtype {images.dtype} is not supported; use uint8, uint16 or a float type")


def load_image(path) -> Tensor:
    """Read an image file as a grey float32 tensor (H, W) in [0, 1]."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such file")
    data = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if data is None or data.size == 0:
        raise InputError(f"{path}: not a readable image file")
    if data.dtype not in (np.uint8, np.uint16):
        raise InputError(f"{path}: pixel type {data.dtype} is not supported (8- or 16-bit images only)")
    scale = 255.0 if data.dtype == np.uint8 else 65535.0
    data = data.astype(np.float32) / scale
    if data.ndim == 3:
        bgr = data[..., :3]
        data = bgr @ np.array(LUMA[::-1], dtype=np.float32)
    return torch.from_numpy(np.ascontiguousarray(data))
