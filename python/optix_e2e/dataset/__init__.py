"""Sharded, resumable PSF datasets: generation (:mod:`.generate`, each shard by :mod:`.shards`), checking
(:mod:`.verify`) and a lazy torch ``Dataset`` (:mod:`.torch_dataset`).  Layout and
guarantees: docs/dataset.md."""

from .generate import GenerateReport, generate
from .layout import DatasetError
from .settings import DatasetSettings
from .verify import verify

__all__ = ["DatasetSettings", "DatasetError", "GenerateReport", "generate", "verify"]
