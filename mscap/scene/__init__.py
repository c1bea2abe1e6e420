"""The scene: settings dataclasses, the TOML loader and its checks, poses, calibration settings."""
