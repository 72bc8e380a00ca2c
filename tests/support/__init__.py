"""What the test modules share, one plain module per need; a test module never imports another
test module. Fixtures with set-up and tear-down live in the conftest.py files."""

from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
