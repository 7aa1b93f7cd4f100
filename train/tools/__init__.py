"""Measurement tools, each run as ``python -m train.tools.<name>``: ``bench`` (training
throughput), ``profile`` (an epoch's parts), ``coldstart`` (a start, phase by phase)."""
