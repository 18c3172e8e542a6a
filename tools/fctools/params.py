"""The one parameter table's facts, read from its source."""
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent.parent


def table_length():
    """How many parameters the one table has (`PARAMS: [Param; N]` in
    firmware/loop/src/params.rs): what every ULog's header lists and
    MAVLink's parameter protocol serves."""
    text = (ROOT / "firmware/loop/src/params.rs").read_text()
    return int(re.search(r"pub const PARAMS: \[Param; (\d+)\]", text).group(1))
