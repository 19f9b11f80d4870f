"""ftorch: task-driven visual feature learning (Piater 2001) as batched torch modules."""
from .errors import InputError
from .images import as_image_batch, load_image
from .primitives import BLOB, CORNER, EDGEL, PartKind
from .record import FeatureSpace, ImageRecords
from .salient import SalientPoints
from .scale_space import ScaleSpace, ScaleSpaceOutput

__all__ = [
    "BLOB", "CORNER", "EDGEL", "FeatureSpace", "ImageRecords", "InputError", "PartKind", "SalientPoints",
    "ScaleSpace", "ScaleSpaceOutput", "as_image_batch", "load_image",
]
