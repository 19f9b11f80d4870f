"""The feature space (chapter 3): the steerable scale space, salient edgels and texels, the
statistical texture of 7.2.1, the image records cached once per image, the feature types and
their batched values (eq. 3.12-3.14), and the regions that bound where a feature looks."""
from .evaluate import FeatureValues, feature_values
from .features import Conjunction, Disjunction, Feature, Geometric, LocalFeature, Texel, Texture, Within
from .primitives import BLOB, CORNER, EDGEL, PartKind
from .record import FeatureSpace, ImageRecords
from .region import Frame, Region
from .salient import SalientPoints
from .scale_space import ScaleSpace, ScaleSpaceOutput

__all__ = [
    "BLOB", "CORNER", "Conjunction", "Disjunction", "EDGEL", "Feature", "FeatureSpace", "FeatureValues", "Frame",
    "Geometric", "ImageRecords", "LocalFeature", "PartKind", "Region", "SalientPoints", "ScaleSpace",
    "ScaleSpaceOutput", "Texel", "Texture", "Within", "feature_values",
]
