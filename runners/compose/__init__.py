"""Composing a sweep: from what the user typed to a validated :class:`~runners.compose.sweep_config.SweepConfig`."""
