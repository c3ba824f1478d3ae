"""Trajectory datasets from outside bgap's simulator, as bgap's trajectory table.

``python -m bgap.datasets sumo [key=value ...]``: a second simulator's labelled traffic
(:mod:`bgap.datasets.sumo`).
``python -m bgap.datasets highd PATH`` / ``ngsim PATH``: published recordings of real
traffic converted (:mod:`bgap.datasets.highd`, :mod:`bgap.datasets.ngsim`).
"""
