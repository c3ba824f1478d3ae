"""Composing any packaged command's config in tests: every command's schemas registered."""

from __future__ import annotations

from omegaconf import DictConfig

from bgap.calibration.config import SCHEMAS as CALIBRATION
from bgap.cmetric.config import SCHEMAS as CMETRIC
from bgap.common import config as plumbing
from bgap.datasets.config import SCHEMAS as DATASETS
from bgap.experiments.config import SCHEMAS as EXPERIMENTS

SCHEMAS = tuple(dict.fromkeys((*DATASETS, *CALIBRATION, *CMETRIC, *EXPERIMENTS)))


def compose(config_name: str, overrides: list[str] | None = None) -> DictConfig:
    """``bgap/conf/<config_name>.yaml`` with overrides, as the command would compose it."""
    return plumbing.compose(config_name, overrides, SCHEMAS)
