"""The DETACH paper's own numbers (Tables I-III), shown as reference rows under our tables.

Keyed like `detach.eval.tables.Table.keys`. The paper's LH column is the mean of the subtask
rates (Table I: CML (0.95 + 0.25 + 0 + 0) / 4 = 0.30), so it goes under `lh_mean`; the paper
has no chained LH rate and no trial counts.

The paper's Table II prints its SGR. and EGR. headers swapped relative to its own definitions:
the column printed as SGR. holds LH / LH1 (0.42 / 0.55 = 0.76 for TokenHSI on LH2, 0.59 / 0.72
= 0.82 for DETACH on LH3), which is EGR by definition. The rows below put every number under
the metric its definition gives, which also agrees with the paper's Table III (DETACH on LH3:
EGR 0.81, SGR 0.13).
"""

from __future__ import annotations

from detach import paper_label

SKILLS: dict[str, dict[str, float]] = {
    # Table I (LH1): Follow, Carry, Climb, Sit, LH1
    "cml": {"follow": 0.95, "carry": 0.25, "climb": 0.00, "sit": 0.00, "lh_mean": 0.30},
    "tokenhsi": {"follow": 1.00, "carry": 1.00, "climb": 0.19, "sit": 0.01, "lh_mean": 0.55},
    "detach": {"follow": 0.98, "carry": 0.97, "climb": 0.51, "sit": 0.42, "lh_mean": 0.72},
}

GENERALIZATION: dict[tuple[str, str], dict[str, float]] = {
    # Table II: Follow, Carry, Follow, Climb, Sit, Time(s), LH, SGR, EGR (LH2 has no climb)
    ("lh2", "tokenhsi"): {"follow": 1.00, "carry": 0.56, "follow_2": 0.13, "sit": 0.01,
                          "time_s": 99.00, "lh_mean": 0.42, "sgr": 0.01, "egr": 0.76},
    ("lh2", "detach"): {"follow": 1.00, "carry": 0.96, "follow_2": 0.67, "sit": 0.16,
                        "time_s": 85.00, "lh_mean": 0.70, "sgr": 0.08, "egr": 0.97},
    ("lh3", "tokenhsi"): {"follow": 1.00, "carry": 0.50, "follow_2": 0.21, "climb": 0.20,
                          "sit": 0.00, "time_s": 102.90, "lh_mean": 0.38, "sgr": 0.67,
                          "egr": 0.69},
    ("lh3", "detach"): {"follow": 1.00, "carry": 0.95, "follow_2": 0.50, "climb": 0.40,
                        "sit": 0.10, "time_s": 97.60, "lh_mean": 0.59, "sgr": 0.13, "egr": 0.81},
}

ABLATION: dict[str, dict[str, float]] = {
    # Table III (LH3): EGR, SGR, LH
    "detach": {"egr": 0.81, "sgr": 0.13, "lh_mean": 0.58},
    "ablation_a1": {"egr": 0.64, "sgr": 0.12, "lh_mean": 0.41},
    "ablation_a2": {"egr": 0.74, "sgr": 0.05, "lh_mean": 0.38},
}

SWAP_NOTE = ("Paper rows: the paper's own numbers. Its Table II prints the SGR. and EGR. "
             "headers swapped relative to its own definitions (the column printed as SGR. holds "
             "LH / LH1 = EGR, e.g. 0.42 / 0.55 = 0.76 for TokenHSI on LH2); here each number "
             "stands under the metric its definition gives, as in the paper's Table III.")


def reference_rows(table: str) -> list[tuple[dict[str, str], dict[str, float]]]:
    """(label cells by key, numbers by key) of the paper's rows for one of our tables."""
    if table == "skills":
        return [({"method": f"paper: {paper_label(m)}"}, v) for m, v in SKILLS.items()]
    if table == "generalization":
        return [({"experiment": task.upper(), "method": f"paper: {paper_label(m)}"}, v)
                for (task, m), v in GENERALIZATION.items()]
    if table == "ablation":
        return [({"method": f"paper: {paper_label(m)}"}, v) for m, v in ABLATION.items()]
    return []
