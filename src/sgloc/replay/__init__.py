"""Replay of recorded multi-robot runs through an online session (`sgloc replay`)."""

from sgloc.replay.stream import ReplayRecord, replay_logs

__all__ = ["ReplayRecord", "replay_logs"]
