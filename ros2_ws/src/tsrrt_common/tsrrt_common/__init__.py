"""Shared tsrrt library code: task-space regions, geometry, scenarios and configuration."""
