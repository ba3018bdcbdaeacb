"""Launch files (YAML) shipped as package data: ``importlib.resources.files("aes_planner.launch")``."""
