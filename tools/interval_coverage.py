"""Print the coverage tables of the study's intervals as Markdown (docs/intervals.md):
1,000 simulated studies per setting, derandomised, about 3 minutes on 2 cores.

    python tools/interval_coverage.py > /tmp/coverage.md
"""

from __future__ import annotations

import sys

import pandas as pd

from bgap.analysis.coverage import (
    coverage_table,
    difference_table,
    paired_table,
    scene_table,
    yardstick_table,
)


def markdown(rows: list[dict], title: str) -> str:
    df = pd.DataFrame(rows)
    cell = df.assign(v=[f"{c:.1%} ({w:.2f})" for c, w in zip(df.coverage, df.width, strict=True)])
    wide = cell.pivot_table(
        index=["setting", "seeds"], columns="method", values="v", aggfunc="first"
    )
    lines = [
        f"### {title}",
        "",
        "| setting | seeds | " + " | ".join(wide.columns) + " |",
        "|---|---|" + "---|" * len(wide.columns),
    ]
    for (setting, seeds), row in wide.iterrows():
        lines.append(f"| {setting} | {seeds} | " + " | ".join(row.fillna("")) + " |")
    return "\n".join(lines) + "\n"


def main(studies: int = 1000) -> None:
    print(
        markdown(coverage_table(studies, episodes=100), "One arm's rate, one cell (100 episodes)")
    )
    print(
        markdown(coverage_table(studies, episodes=700), "One arm's rate, one claim (700 episodes)")
    )
    print(markdown(difference_table(studies), "Two arms on the same 700 episodes"))
    print(
        markdown(paired_table(studies), "The same models in two conditions (300 and 600 episodes)")
    )
    print(markdown(scene_table(studies), "The same models on the same 700 scenes (two radii)"))
    print(markdown(yardstick_table(studies), "Learned policies against a yardstick (700 episodes)"))


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 1000)
