"""Learning to pre-shape a grasp (chapter 6): von Mises orientation models (eq. 6.1-6.5) and the
grasp learner that recommends finger count and hand orientation (alg. 6.1, 6.2)."""
from .feature_set import Experience
from .learner import GraspLearner, Learned, Recommendation
from .settings import MU0_CAP, POOR_MU0, FingerChoice, GraspSettings
from .vonmises import VonMisesMixture, fit_mixture, fit_mixtures

__all__ = ["Experience", "FingerChoice", "GraspLearner", "GraspSettings", "Learned", "MU0_CAP", "POOR_MU0", "Recommendation",
           "VonMisesMixture", "fit_mixture", "fit_mixtures"]
