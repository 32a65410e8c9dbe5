"""Episode data contract (Parquet per episode) and dataset folders (manifest + splits)."""

from .dataset import SPLITS, Dataset, load_dataset, read_manifest, write_dataset
from .episode import (
    SCHEMA_VERSION,
    Episode,
    columns_for,
    read_episode,
    read_metadata,
    validate_episode,
    write_episode,
)

__all__ = [
    "SCHEMA_VERSION",
    "SPLITS",
    "Dataset",
    "Episode",
    "columns_for",
    "load_dataset",
    "read_episode",
    "read_manifest",
    "read_metadata",
    "validate_episode",
    "write_dataset",
    "write_episode",
]
