"""Fetches an OpenMetrics endpoint and parses it with an independent
parser (the Python prometheus_client's strict OpenMetrics parser); prints
every sample as one JSON line: {"name", "labels", "value"}. Exits 1 with
the parser's message if the text is not valid OpenMetrics.

Usage: python openmetrics.py http://127.0.0.1:PORT/metrics
"""
import json
import sys
import urllib.request

from prometheus_client.openmetrics.parser import text_string_to_metric_families


def main() -> int:
    with urllib.request.urlopen(sys.argv[1], timeout=10) as r:
        kind = r.headers.get("Content-Type", "")
        text = r.read().decode("utf-8")
    if not kind.startswith("application/openmetrics-text"):
        print(f"content type {kind!r} is not OpenMetrics", file=sys.stderr)
        return 1
    try:
        for family in text_string_to_metric_families(text):
            for s in family.samples:
                print(json.dumps({"name": s.name, "labels": s.labels, "value": s.value}))
    except ValueError as e:
        print(f"not valid OpenMetrics: {e}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
