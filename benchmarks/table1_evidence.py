"""Table 1 of docs/evidence/table1.md, measured again and written into the page (never copied by hand).

Runs ``vpr-uncertainty reproduce`` on the config of the tutorial "Reproduce the study" (its TOML block) with its
first input only (the ten VPR-Bench corridor matrices; the data paths pointed at ``VPR_UNCERTAINTY_DATA``), and
replaces the page's table, between its markers, by the ``table1.md`` the run writes. ``--check`` writes nothing and
exits 1 when the page's table differs from the run's in anything but the ms/query column (a timing).

Usage: ``VPR_UNCERTAINTY_DATA=... python benchmarks/table1_evidence.py [--out runs/table1-evidence] [--check]``
(about 2 minutes on 2 cores: GV-SIFT extracts the corridor's local features once).
"""

from __future__ import annotations

import argparse
import os
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TUTORIAL = ROOT / "docs" / "tutorials" / "reproduce-the-study.md"
PAGE = ROOT / "docs" / "evidence" / "table1.md"
BEGIN = "<!-- table: written by benchmarks/table1_evidence.py -->\n"
END = "<!-- end of the table written by benchmarks/table1_evidence.py -->\n"


def evidence_config(data_root: Path) -> str:
    """The tutorial's config, first ``[[inputs]]`` only, its ``../shared/data`` paths at ``data_root``."""
    config = re.findall(r"```toml\n(.*?)```", TUTORIAL.read_text(encoding="utf-8"), re.S)[0]  # reproduce.toml
    second = [match.start() for match in re.finditer(r"^\[\[inputs\]\]", config, re.M)][1]
    return config[:second].replace('"../shared/data', f'"{data_root.resolve()}')


def without_timings(table: str) -> list[str]:
    """The table's rows without their last cell (ms/query)."""
    return [line.rsplit("|", 2)[0] for line in table.strip().splitlines()]


def page_table(page: str) -> str:
    return page[page.index(BEGIN) + len(BEGIN) : page.index(END)]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=ROOT / "runs" / "table1-evidence", help="the run's folder")
    parser.add_argument("--check", action="store_true", help="compare with the page instead of writing it")
    args = parser.parse_args()
    data_root = Path(os.environ["VPR_UNCERTAINTY_DATA"])
    args.out.mkdir(parents=True, exist_ok=True)
    config = args.out / "reproduce.toml"
    config.write_text(evidence_config(data_root).replace('out = "runs/reproduce"', 'out = "."'), encoding="utf-8")
    from vpr_uncertainty.cli import main as vpr_uncertainty

    if vpr_uncertainty(["reproduce", str(config)]) != 0:
        return 1
    table = (args.out / "table1.md").read_text(encoding="utf-8")
    table = table[: table.index("\n\n")] + "\n"  # the table, without the legend the page states once
    page = PAGE.read_text(encoding="utf-8")
    if args.check:
        same = without_timings(page_table(page)) == without_timings(table)
        print(f"{PAGE.relative_to(ROOT)}: {'matches' if same else 'differs from'} the run's table1.md")
        return 0 if same else 1
    PAGE.write_text(page.replace(page_table(page), table), encoding="utf-8")
    print(f"wrote the table of {PAGE.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
