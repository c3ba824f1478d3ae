"""The model's vocabulary: names, codes and constants every part of bgap shares.

A leaf module: it imports nothing of bgap and no simulator, so anything may import it
(CMetric's command too, which knows no simulator). The road's, the vehicles' and the ego's
action constants, which highway-env defines, are :mod:`bgap.traffic.road`'s.
"""

from __future__ import annotations

# ---------------------------------------------------------------- driver classes
EGO, CONSERVATIVE, AGGRESSIVE = "ego", "conservative", "aggressive"
CLASSES = (CONSERVATIVE, AGGRESSIVE)
"""Background driver classes, in the order of the behaviour presets."""
LABEL_CODES = {EGO: 0, CONSERVATIVE: 1, AGGRESSIVE: 2}
"""Integer code of each label in array layouts (vector backend state, recorded frames)."""
LABEL_NAMES = {code: name for name, code in LABEL_CODES.items()}
COLORS = {EGO: (50, 200, 0), AGGRESSIVE: (220, 40, 40), CONSERVATIVE: (40, 90, 220)}
"""Paper figure colours (RGB): ego green, aggressive red, conservative blue."""

# ---------------------------------------------------------------- the vector backend
FINISHED = -1
"""The vector backend's "no action": the env's episode is over and no longer counted, so
the step leaves it as it is (no simulation, no automatic reset); :func:`bgap.sim.rollout`
sends it to envs whose first episode ended."""

# ---------------------------------------------------------------- experiment names
POLICIES = ("behavior_rich", "default")
"""Trained policy families: trained in behaviour-rich traffic, or in stock traffic."""
BASELINES = ("idle", "random", "left", "rule", "rule_tuned", "idm")
"""Scripted ego policies evaluated beside trained ones (``rule``: IDM + MOBIL over the
meta-actions with highway-env's parameters, ``rule_tuned`` with tuned ones, ``idm``: IDM in
its lane; :mod:`bgap.agents.rule_based`)."""
YARDSTICK_NAMES = {
    "rule": "the rule-based ego",
    "rule_tuned": "the tuned rule-based ego",
    "idm": "IDM in its lane",
}
"""The hand-built drivers a learned policy is read against, and their names in prose: it
"beats the hand-built driver" only by beating each of them."""
YARDSTICKS = tuple(YARDSTICK_NAMES)
LEARNERS = ("sb3", "batched")
"""Training algorithms' implementations: Stable-Baselines3's DQN (the reference, one training
per process) and :mod:`bgap.agents.batched` (many trainings in lock step)."""
CHECKPOINTS = ("best", "last")
"""Which parameters of a training are evaluated: the validation-selected checkpoint or the
final ones."""
CHECKPOINT_RULES = ("return", "per_km")
"""How a training chooses its best checkpoint among its validations: the highest mean return
(SB3's ``EvalCallback``), or the fewest collisions per 100 km at a speed floor."""
BACKENDS = ("highway", "vector")
"""Simulators: highway-env (the reference) and bgap's vectorised port."""
MIX_SAMPLING = ("fixed", "uniform", "paper")
"""Training mix per episode: the configured mix, uniform in [0, 1], or a paper mix."""
PAPER_MIXES = (0.0, 0.2, 0.4, 0.5, 0.6, 0.8, 1.0)
"""Aggressive fractions of the paper's evaluation grid."""
SPEED_FLOOR = 0.9
"""A policy beats the idle ego when it crashes less at a mean speed of at least this fraction
of idle's on the same episodes: safety bought by crawling is no win (ours). The
same rule ranks recipe candidates (:func:`bgap.common.scores.constrained_score`)."""
FLOOR_BAND = 0.05
"""A training's checkpoint rule counts :data:`SPEED_FLOOR` as met within this fraction below
it (ours): one training's validation speeds spread over a few m/s, and a floor at the edge
of that spread would keep whichever validation scraped over it, whatever it crashed."""
ENDINGS = ("timeout", "rear_end", "rear_ended", "lane_change", "other")
"""How an episode ended: it ran its full duration; the ego ran into a vehicle ahead; a
vehicle ran into the ego from behind; contact during or within 2 s after an ego lane change;
a crash whose partner was not reported (``bgap.rollout.EpisodeStats``)."""
CRASH_KINDS = ENDINGS[1:]
LANE_CHANGE_WINDOW = 2.0
"""Seconds after the start of an ego lane change during which a crash counts as its doing."""
