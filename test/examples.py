"""The runnable examples of docs/examples, importable by the tests (they import each other by name)."""
import sys
from pathlib import Path

EXAMPLES = Path(__file__).resolve().parents[1] / "docs" / "examples"
if str(EXAMPLES) not in sys.path:
    sys.path.insert(0, str(EXAMPLES))

import bearings_only  # noqa: E402
import bearings_only_peers  # noqa: E402
import growth_model  # noqa: E402
import own_sensor  # noqa: E402

__all__ = ["EXAMPLES", "bearings_only", "bearings_only_peers", "growth_model", "own_sensor"]
