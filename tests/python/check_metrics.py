"""Parses a `/metrics` exposition with Prometheus's reference Python parsers and prints its samples.

An independent reading of what the coordinator and workers serve (they encode with the Rust
prometheus-client crate): the strict OpenMetrics parser must accept the text whole (families
declared once, suffixes that fit their types, cumulative buckets, the closing `# EOF`), and the
classic text-format parser must read the same samples. Prints one JSON list of samples
`{"family", "type", "name", "labels", "value"}`; any violation exits non-zero with the parser's
message.

    python tests/python/check_metrics.py EXPOSITION_FILE
"""

import json
import sys
from pathlib import Path

from prometheus_client.openmetrics.parser import text_string_to_metric_families as openmetrics_families
from prometheus_client.parser import text_string_to_metric_families as text_format_families


def samples(text: str) -> list[dict[str, object]]:
    """Every sample of `text`, read by the OpenMetrics parser and checked against the text-format one."""
    found: list[dict[str, object]] = []
    strict = []
    for family in openmetrics_families(text):
        for s in family.samples:
            found.append(
                {
                    "family": family.name,
                    "type": family.type,
                    "name": s.name,
                    "labels": s.labels,
                    "value": s.value,
                }
            )
            strict.append((s.name, sorted(s.labels.items()), s.value))
    classic = [
        (s.name, sorted(s.labels.items()), s.value) for f in text_format_families(text) for s in f.samples
    ]
    if sorted(classic) != sorted(strict):
        raise ValueError(f"the text-format parser read {len(classic)} samples, OpenMetrics {len(strict)}")
    return found


def main() -> int:
    if len(sys.argv) != 2:
        print("usage: check_metrics.py EXPOSITION_FILE", file=sys.stderr)
        return 2
    try:
        found = samples(Path(sys.argv[1]).read_text(encoding="utf-8"))
    except ValueError as e:
        print(f"not a valid exposition: {e}", file=sys.stderr)
        return 1
    json.dump(found, sys.stdout)
    return 0


if __name__ == "__main__":
    sys.exit(main())
