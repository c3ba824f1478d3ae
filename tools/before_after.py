"""The retrained study beside the study it replaces: per arm, density and family, where the
kept checkpoints lie in training and the lane changes per episode; the sparse rows against
the rule-based ego; and the headline claim, before and after (the comparison the retraining's
research note and results page give).

    python tools/before_after.py --before 4a9ea40              # against the working tree
    python tools/before_after.py --before 4a9ea40 --after HEAD > before_after.md

``--before`` and ``--after`` are commits (``--after`` defaults to the working tree). Each
side is read from its committed results: ``results/evaluation/<arm>/paper/models.csv`` (the
kept checkpoints: ``chosen_episodes`` of ``validated_episodes``) and ``episodes.parquet``
(lane changes per episode in bgap's traffic at the largest radius, mixes that repeat another's
traffic once), ``results/yardsticks.csv`` (sparse, against ``rule``) and
``results/claims.csv`` (the headline claim). An arm one side lacks shows as a dash.
"""

from __future__ import annotations

import subprocess
import sys
import tarfile
import tempfile
from io import BytesIO
from pathlib import Path

import pandas as pd

from bgap.analysis.episodes import parse_policies, policy_parts
from bgap.analysis.paper import HEADLINE
from bgap.analysis.yardsticks import read_cells

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run as a script: tools.*
from tools.cli import OneLineParser  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
"""The repository (this file is tools/before_after.py)."""
READ = ["results/evaluation", "results/yardsticks.csv", "results/claims.csv"]
"""What each side is read from."""
EARLY = 0.2
"""A checkpoint kept in this first share of training counts as early."""


def checkout(rev: str, into: Path, root: Path = ROOT) -> Path:
    """The files :data:`READ` of commit ``rev`` extracted under ``into``."""
    listed = subprocess.run(
        ["git", "ls-tree", "--name-only", rev, "--", *READ], cwd=root, capture_output=True
    )
    present = listed.stdout.decode().split() if listed.returncode == 0 else READ
    done = subprocess.run(
        ["git", "archive", rev, *present], cwd=root, capture_output=True, check=False
    )
    if done.returncode:
        raise SystemExit(f"tools/before_after.py: {rev!r}: {done.stderr.decode().strip()}")
    with tarfile.open(fileobj=BytesIO(done.stdout)) as tar:
        tar.extractall(into, filter="data")
    return into


def checkpoints(root: Path) -> pd.DataFrame:
    """Per arm, density and family: policies, kept in the first fifth, median position."""
    rows = []
    for path in sorted((root / "results/evaluation").glob("*/paper/models.csv")):
        m = pd.read_csv(path)
        m = pd.concat([m, policy_parts(m.policy)[["arm", "density", "family"]]], axis=1)
        m = m[m.family.notna()]  # trained policies only
        m["position"] = m.chosen_episodes / m.validated_episodes
        for (arm, density, family), g in m.groupby(["arm", "density", "family"]):
            rows.append({"arm": arm, "density": density, "family": family,
                         "policies": len(g), "early": int((g.position <= EARLY).sum()),
                         "median_position": float(g.position.median())})  # fmt: skip
    return pd.DataFrame(rows)


def lane_changes(root: Path) -> pd.DataFrame:
    """Per arm, density and family: mean lane changes per episode in bgap's traffic at the
    largest radius (repeated mixes once)."""
    rows = []
    for path in sorted((root / "results/evaluation").glob("*/paper/episodes.parquet")):
        df = parse_policies(pd.read_parquet(path))
        df = df[df.arm != ""]
        for density in sorted(set(df.density)):
            for (arm, family), g in read_cells(df, density).groupby(["arm", "family"]):
                rows.append({"arm": arm, "density": density, "family": family,
                             "lane_changes": float(g.lane_changes.mean())})  # fmt: skip
    return pd.DataFrame(rows)


def side(root: Path) -> dict[str, pd.DataFrame]:
    """One side's tables: checkpoints and lane changes, sparse rows, headline claims."""
    per_policy = checkpoints(root)
    lanes = lane_changes(root)
    if len(per_policy) and len(lanes):
        per_policy = per_policy.merge(lanes, on=["arm", "density", "family"], how="outer")
    yards = root / "results/yardsticks.csv"
    sparse = pd.read_csv(yards) if yards.exists() else pd.DataFrame()
    if len(sparse):
        sparse = sparse[(sparse.density == "sparse") & (sparse.yardstick == "rule")]
    claims = root / "results/claims.csv"
    headline = pd.read_csv(claims) if claims.exists() else pd.DataFrame()
    if len(headline):
        headline = headline[headline.claim == HEADLINE]
    return {"policies": per_policy, "sparse": sparse, "headline": headline}


def _cell(value: object, fmt: str) -> str:
    return "-" if value is None or pd.isna(value) else format(value, fmt)


def _verdict(r: dict, s: str) -> str:
    v = r.get(f"verdict_{s}")
    return v if isinstance(v, str) else "-"


def _joined(before: pd.DataFrame, after: pd.DataFrame, key: list[str]) -> pd.DataFrame:
    if before.empty and after.empty:
        return pd.DataFrame(columns=key)
    b = before if len(before) else pd.DataFrame(columns=after.columns)
    a = after if len(after) else pd.DataFrame(columns=before.columns)
    return b.merge(a, on=key, how="outer", suffixes=("_before", "_after")).sort_values(key)


def _section(title: str, table: pd.DataFrame, key: list[str], cell) -> list[str]:
    """A before/after table: its bold title, then per row its ``key`` and ``cell(row, side)``
    for each side."""
    lines = [
        f"\n**{title}\n",
        f"| {' | '.join(key)} | before | after |",
        "|---" * (len(key) + 2) + "|",
    ]
    for r in table.to_dict("records"):
        keys = " | ".join(str(r[k]) for k in key)
        lines.append(f"| {keys} | {cell(r, 'before')} | {cell(r, 'after')} |")
    return lines


def markdown(before: dict, after: dict) -> str:
    """The three comparisons as Markdown tables (module docstring)."""
    key = ["arm", "density", "family"]
    pol = _joined(before["policies"], after["policies"], key)
    lines = [
        "**Kept checkpoints and lane changes** (per arm, density and family: policies kept "
        f"in the first {EARLY:.0%} of training, the median position, lane changes per "
        "episode)\n",
        "| arm | density | family | early, before | early, after | median position, before "
        "| after | lane changes, before | after |",
        "|---" * 9 + "|",
    ]
    for r in pol.to_dict("records"):
        early = [
            f"{_cell(r.get(f'early_{s}'), '.0f')} of {_cell(r.get(f'policies_{s}'), '.0f')}"
            for s in ("before", "after")
        ]
        lines.append(
            f"| {r['arm']} | {r['density']} | {r['family']} | {early[0]} | {early[1]} | "
            f"{_cell(r.get('median_position_before'), '.0%')} | "
            f"{_cell(r.get('median_position_after'), '.0%')} | "
            f"{_cell(r.get('lane_changes_before'), '.2f')} | "
            f"{_cell(r.get('lane_changes_after'), '.2f')} |"
        )
    lines += _section(
        "Sparse, against the rule-based ego** (collisions per 100 km: policy / rule, verdict)",
        _joined(before["sparse"], after["sparse"], ["arm", "family"]),
        ["arm", "family"],
        lambda r, s: (
            f"{_cell(r.get(f'per_100km_{s}'), '.2f')} / "
            f"{_cell(r.get(f'yard_per_100km_{s}'), '.2f')}, {_verdict(r, s)}"
        ),
    )
    lines += _section(
        f"The headline claim** ({HEADLINE}: difference in % of episodes [95% CI], verdict)",
        _joined(before["headline"], after["headline"], ["arm", "n"]),
        ["arm", "n"],
        lambda r, s: (
            f"{_cell(r.get(f'difference_{s}'), '+.1f')} [{_cell(r.get(f'lo_{s}'), '+.1f')}, "
            f"{_cell(r.get(f'hi_{s}'), '+.1f')}], {_verdict(r, s)}"
        ),
    )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    parser = OneLineParser(prog="tools/before_after.py", description=__doc__.split("\n\n")[0])
    parser.add_argument("--before", required=True, help="the commit of the replaced study")
    parser.add_argument("--after", help="the commit of the retrained one (default: work tree)")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        before = side(checkout(args.before, Path(tmp) / "before"))
        after_root = ROOT if args.after is None else checkout(args.after, Path(tmp) / "after")
        print(markdown(before, side(after_root)), end="")


if __name__ == "__main__":
    main()
