"""Recognition and expert learning (chapters 4-5): class networks of distinctive features (4.4),
recognition by querying them (alg. 4.4), and the incremental learner (alg. 4.7-4.10, 5.1-5.2)
with its parts: the instance list and counts, candidate generation, expert pair choice."""
from .bayes import ClassNetwork
from .environment import ImageSet
from .explain import Explanation
from .inference import Answer, Outcome, Recognition, Result, accuracy, outcome, recognize, top1_accuracy, top_class
from .learner import DistinctiveFeatureLearner
from .learning import Presentation
from .settings import Distinctions, Evidence, LearnerSettings
from .stages import ClassAdded, Cycle, Schedule, Stage

__all__ = ["Answer", "ClassAdded", "ClassNetwork", "Cycle", "DistinctiveFeatureLearner", "Distinctions", "Evidence",
           "Explanation", "ImageSet", "LearnerSettings", "Outcome", "Presentation", "Recognition", "Result", "Schedule",
           "Stage", "accuracy", "outcome", "recognize", "top1_accuracy", "top_class"]
