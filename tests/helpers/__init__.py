"""Shared test helpers: scenes, task copies, the local VLM server, robot tool paths."""
