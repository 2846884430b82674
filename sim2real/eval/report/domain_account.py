"""A policy's training domain in the soak's report: its account (each value with where it came
from, each key the soak does not model; :func:`sim2real.eval.world.domain.domain_account`) as
report.html's ``training domain`` table (:func:`domain_table`) and one summary line
(:func:`domain_summary`), from report.json's ``campaign.training_domain`` (the domain's text)."""

from __future__ import annotations

from collections.abc import Callable

from sim2real.eval.world.domain import ACCOUNT_PREFIXES, domain_account


def domain_table(report: dict, table: Callable[[list[str], list[list]], dict]) -> dict | None:
    """The account as a table (``table(header, rows)``: report.html's): one row a line, its
    kind (``from``, ``not modelled``, ``off``) and its text; None without an account (no
    domain, or one written without it)."""
    text = report["campaign"].get("training_domain")
    lines = domain_account(text) if isinstance(text, str) else []
    if not lines:
        return None
    rows = []
    for line in lines:
        prefix = next(p for p in ACCOUNT_PREFIXES if line.startswith(p))
        rows.append([prefix[2:-2], line[len(prefix) :]])
    return table(["training domain", "value <- where it came from, or what is left out"], rows)


def domain_summary(text) -> list[str]:
    """One summary line of the account of domain ``text``: its values with a source, the keys
    the soak does not model (the first of each line's keys); none without an account."""
    lines = domain_account(text) if isinstance(text, str) else []
    if not lines:
        return []
    apart = [line[len("# not modelled: ") :] for line in lines if line.startswith("# not mod")]
    values = sum(line.startswith("# from: ") for line in lines)
    keys = ", ".join(line.split(" ", 1)[0] for line in apart)
    return [
        f"  domain       the policy's training domain: {values} values each with its source "
        "(report.html 'training domain'; report.json campaign.training_domain)"
        + (f"; not modelled: {keys}" if apart else "")
    ]
