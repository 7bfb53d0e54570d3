"""Peer benchmark: sgloc's rejectors against point-cloud registration peers (run.py)."""
