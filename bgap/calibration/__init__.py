"""Calibrating the driver classes: to CMetric score targets (the paper's mode) or to the
statistics of an observed, labelled trajectory table."""
