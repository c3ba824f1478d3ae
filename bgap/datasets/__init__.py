"""Trajectory datasets from outside bgap's simulator, as bgap's trajectory table.

``python -m bgap.datasets sumo [key=value ...]``: a second simulator's labelled traffic
(:mod:`bgap.datasets.sumo`).
"""
