"""The names of the line-ups' learners, in one place.

A learner's name is its key in the run records, the tables' ``learner`` column, the claims and
the figures' legends; the line-ups (:mod:`.learners`), the claims (:mod:`.claims`) and the
figures (:mod:`.figures`) refer to the learners through these constants only.
"""

from __future__ import annotations

__all__ = [
    "FLAT", "FLAT_GROUND_TRUTH", "FLAT_PCA_FEATURES", "FLAT_FEATURES_FROM_EXAMPLES", "FLAT_FEATURES",
    "FACTORIAL", "FACTORIAL_RANDOM_INIT", "FACTORIAL_FEATURES", "FACTORIAL_FEATURES_RANDOM_INIT",
    "FLAT_MCE", "FACTORIAL_MCE", "FLAT_MCE_FEATURES", "FACTORIAL_MCE_FEATURES", "FACTORIAL_MCE_FEATURES_RANDOM_INIT",
    "ADAPTIVE", "ADAPTIVE_FEATURES",
]

#: GradIRL on tabular rewards, one task at a time (the paper's flat learner)
FLAT = "flat"
#: GradIRL with the true dictionary (primitives) as features: the floor
FLAT_GROUND_TRUTH = "flat, ground truth"
#: GradIRL with the PCA components of the flat training rewards as features
FLAT_PCA_FEATURES = "flat, PCA features"
#: GradIRL with learnt flat training rewards as features
FLAT_FEATURES_FROM_EXAMPLES = "flat, features from ex."
#: GradIRL on the world's base features
FLAT_FEATURES = "flat, features"
#: FactIRL from the PCA of the flat rewards (train), its transfer (test)
FACTORIAL = "factorial"
#: FactIRL from a random start
FACTORIAL_RANDOM_INIT = "factorial, random init"
#: FactIRL on the world's base features, from the PCA of ``flat, features``
FACTORIAL_FEATURES = "factorial, features"
#: FactIRL on the base features from a random start
FACTORIAL_FEATURES_RANDOM_INIT = "factorial, features, random init"
#: GradIRL on the maximum causal entropy likelihood
FLAT_MCE = "flat MCE"
#: FactIRL on the maximum causal entropy likelihood, from the PCA of ``flat MCE``
FACTORIAL_MCE = "factorial MCE"
#: GradIRL on the MCE likelihood and the base features
FLAT_MCE_FEATURES = "flat MCE, features"
#: FactIRL on the MCE likelihood and the base features
FACTORIAL_MCE_FEATURES = "factorial MCE, features"
#: FactIRL on the MCE likelihood and the base features from a random start
FACTORIAL_MCE_FEATURES_RANDOM_INIT = "factorial MCE, features, random init"
#: FactIRL with k and the residual penalty chosen by validation (``"auto"``), tabular, from the PCA of ``flat``
ADAPTIVE = "adaptive"
#: the same on the base features, from the PCA of ``flat, features``
ADAPTIVE_FEATURES = "adaptive, features"
