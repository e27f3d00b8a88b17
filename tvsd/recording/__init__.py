"""Recordings: the CSV contract of DESIGN.md (`csvfile`) and the daemon's crash-safe segment files
(`format`, written by `writer`, read back by `reader`)."""
