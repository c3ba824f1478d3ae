"""Optuna searching CMetric's own parameters: ``python -m bgap.cmetric.search``.

The search reads labelled trajectory tables (any table CMetric reads, with a ``label``
column of ``aggressive`` / ``conservative``; other labels, the ego among them, are not
scored for the AUC). It maximises the **worst** ROC AUC over the datasets of its search
part: a parameter set that is excellent in dense traffic and blind in sparse traffic loses
to one that is good in both.

- **Split by episode.** Even episode numbers form the search part, odd ones the validation
  part, in every dataset marked ``split`` (bgap's simulator numbers episodes by seed, so
  the two parts are disjoint seeds). A dataset with ``split: false`` (another simulator's
  data) is validation only: it never tunes.
- **Flagged vehicles** (no evidence, :mod:`bgap.cmetric.score`) count at the median score,
  and a dataset with more than ``max_flagged`` of its vehicles flagged costs the trial the
  excess (a search may not buy AUC by flagging the hard cases).
- **Crops.** ``radius`` keeps only the vehicles within that distance of the ego (rows with
  ``is_ego``) in each frame: the traffic a car's own sensors would have recorded.

Storage as calibration and sweeps: SQLite under the output folder by default, any Optuna
URL, resumable (a rerun completes the study to ``trials``). The chosen parameters are
written as a ``cmetric`` preset, with a report comparing the default, the starting preset
and the tuned one on both parts of every dataset.
"""
