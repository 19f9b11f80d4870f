"""ftorch: task-driven visual feature learning (Piater 2001) as batched torch modules.

One package per part of the thesis, in the order data flows through them: :mod:`ftorch.space`
(chapter 3, the feature space), :mod:`ftorch.recognition` (chapters 4-5, recognition and expert
learning) and :mod:`ftorch.grasp` (chapter 6, grasp pre-shaping); input rules, errors and
checkpoints are shared by all three.
"""
from .errors import InputError, NotFittedError
from .grasp import GraspLearner
from .images import as_image_batch, load_image
from .recognition import Answer, DistinctiveFeatureLearner, ImageSet, LearnerSettings
from .space import BLOB, CORNER, EDGEL, FeatureSpace, ImageRecords, PartKind, SalientPoints, ScaleSpace, ScaleSpaceOutput, feature_values
from .vml import resolve_vml

resolve_vml()  # before any parallel float op can run: see ftorch.vml

__all__ = [
    "Answer", "BLOB", "CORNER", "DistinctiveFeatureLearner", "EDGEL", "FeatureSpace", "GraspLearner", "ImageRecords", "ImageSet",
    "InputError", "LearnerSettings", "NotFittedError", "PartKind", "SalientPoints", "ScaleSpace", "ScaleSpaceOutput",
    "as_image_batch", "feature_values",
    "load_image",
]
