"""Summarise held-out key experiments (rows written by pooled_priority.py, budget_eccentricity.py,
detail_contrast.py, relit_deviation.py): per variant, JOD minus today's perceptual keys over the budget
rows (median, mean, how many better, medians per budget) and, for rows with ``budget: null`` (imperceptible
cuts), each variant's JOD range and triangles against today's.

    .venv/bin/python reports/accuracy/scripts/summarise_heldout.py OUT.md ROWS.jsonl [ROWS.jsonl ...]
"""
import json
import sys
from pathlib import Path

import numpy as np

HEAD = {"mesh", "gaze", "budget", "tris", "perceptual", "s"}


def table(rows):
    budget = [r for r in rows if r.get("budget") is not None]
    cols = [k for k in budget[0] if k not in HEAD and not k.endswith("_tris")] if budget else []
    budgets = sorted({r["budget"] for r in budget})
    out = ["| keys | median | mean | better in | " + " | ".join(f"{b:.0%}" for b in budgets) + " (medians) |",
           "| --- | ---: | ---: | ---: | " + " | ".join("---:" for _ in budgets) + " |"]
    for c in cols:
        d = np.array([r[c] - r["perceptual"] for r in budget])
        per = [np.median([r[c] - r["perceptual"] for r in budget if r["budget"] == b]) for b in budgets]
        out.append(f"| {c} | {np.median(d):+.3f} | {d.mean():+.3f} | {(d > 0).sum()} / {len(d)} | "
                   + " | ".join(f"{x:+.3f}" for x in per) + " |")
    imp = [r for r in rows if r.get("budget") is None]
    if imp:
        out += ["", "Imperceptible cuts (rows without a budget): JOD min - max, triangles against today's (min - max):", ""]
        for c in ["perceptual"] + [k for k in imp[0] if k not in HEAD and not k.endswith("_tris")]:
            j = [r[c] for r in imp]
            t = [r[c + "_tris"] / r["perceptual_tris"] for r in imp] if c != "perceptual" else [1.0]
            out.append(f"- {c}: {min(j):.3f} - {max(j):.3f} JOD, {min(t):.2f} - {max(t):.2f}x the triangles")
    return out


def main():
    lines = []
    for path in sys.argv[2:]:
        rows = [json.loads(x) for x in open(path) if x.strip()]
        n = len([r for r in rows if r.get("budget") is not None])
        lines += [f"## `{path}` ({n} budget rows; JOD minus today's perceptual keys)", ""] + table(rows) + [""]
    Path(sys.argv[1]).write_text("\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
