"""evaluate stage: closed-loop behavioural equivalence (CBE) metrics, tables and figures.

Public API: :func:`evaluate_checkpoint`, :func:`evaluate_models`, :class:`EvaluateConfig`,
:func:`cbe_metrics`, :func:`episode_errors` (which episodes hold the error),
:func:`regression_metrics`, :func:`markdown_table`, :data:`PAPER_TABLE_II`,
:func:`model_card` / :func:`card_markdown` (what a checkpoint is, ``exsur info``),
:func:`dataset_card` / :func:`dataset_card_markdown` (what a dataset holds),
:func:`episode_card` (one episode file), :func:`horizon_errors` (the angle error n seconds
after measured starts).
"""

from .card import card_markdown, model_card
from .cbe import EvaluateConfig, evaluate_checkpoint, evaluate_models
from .data_card import dataset_card, dataset_card_markdown, episode_card
from .horizon import horizon_errors
from .metrics import cbe_metrics, episode_errors, min_r2, regression_metrics
from .report import PAPER_TABLE_II, comparison_table, markdown_table, report_markdown

__all__ = [
    "PAPER_TABLE_II",
    "EvaluateConfig",
    "card_markdown",
    "cbe_metrics",
    "comparison_table",
    "dataset_card",
    "dataset_card_markdown",
    "episode_card",
    "episode_errors",
    "evaluate_checkpoint",
    "evaluate_models",
    "horizon_errors",
    "markdown_table",
    "min_r2",
    "model_card",
    "regression_metrics",
    "report_markdown",
]
