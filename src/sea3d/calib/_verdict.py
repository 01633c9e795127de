"""The verdict of a calibration (stereo or port): one wording for both assessments."""

from __future__ import annotations

from sea3d._text import plural

__all__ = ["MIN_TRUSTED_PAIRS", "VERDICTS", "verdict"]

VERDICTS = ("trusted", "usable with care", "not trusted")
"""Severity 0, 1 and 2."""

MIN_TRUSTED_PAIRS = 10
"""Fewer pairs than this make a calibration "usable with care" at best."""


def verdict(
    notes: list[str],
    severity: int,
    *,
    subject: str,
    trusted_because: str,
    n_pairs: int,
    pairs_to_capture: str,
    n_rejected: int,
) -> tuple[str, list[str]]:
    """``(verdict, sentences)`` of an assessment whose own checks gave ``notes`` and
    ``severity`` (0 trusted, 1 care, 2 not trusted).

    Adds what every calibration is judged on: too few pairs (first; at least "usable with
    care") and pairs left out (last), then heads the sentences with the verdict.

    Args:
        notes: the assessment's own sentences, in order.
        severity: the worst of its checks.
        subject: ``"calibration"`` or ``"port calibration"``.
        trusted_because: why a trusted one is, e.g. ``"low error on held-out views and good
            coverage"``.
        n_pairs: pairs used.
        pairs_to_capture: what to capture, e.g. ``"15-25 pairs"``.
        n_rejected: pairs left out.
    """
    first: list[str] = []
    if n_pairs < MIN_TRUSTED_PAIRS:
        first.append(f"Only {plural(n_pairs, 'pair')} {'was' if n_pairs == 1 else 'were'} used; "
                     f"capture {pairs_to_capture} for a reliable {subject}.")
        severity = max(severity, 1)
    last: list[str] = []
    if n_rejected:
        last.append(f"{plural(n_rejected, 'pair')} {'was' if n_rejected == 1 else 'were'} left "
                    "out; the reasons are listed with the views.")
    word = VERDICTS[severity]
    head = {
        "trusted": f"The {subject} can be trusted: {trusted_because}.",
        "usable with care": f"The {subject} is usable, but the points below would make it more "
                            "reliable.",
        "not trusted": f"Do not trust this {subject} yet; fix the points below and recalibrate.",
    }[word]
    return word, [head, *first, *notes, *last]
