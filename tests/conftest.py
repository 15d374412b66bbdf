"""Test-wide settings: hypothesis runs derandomised, so every run (and CI) checks the same examples."""
from hypothesis import settings

settings.register_profile("torchtea", derandomize=True, print_blob=True)
settings.load_profile("torchtea")
