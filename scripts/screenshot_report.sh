#!/usr/bin/env bash
# Render an agrivio HTML report in headless Chromium and save a full-page screenshot (PNG).
#
#   scripts/screenshot_report.sh REPORT.html [OUT.png] [WIDTHxHEIGHT]
#
# Defaults: OUT.png = REPORT.png next to the report, window 1400x3000 (tall enough for the tables and the first
# figures). Needs Debian's `chromium` (apt-get install -y chromium); exits 3 with a message if it is missing.
# The report is self-contained (inline CSS, base64 figures), so no network is needed; the flags below also keep
# Chromium from trying (no background networking, no component updates, no first-run tasks).
#
# To look at a sample without real runs:
#   .venv/bin/python scripts/make_sample_runs.py /tmp/sample_runs && .venv/bin/agrivio compare /tmp/sample_runs \
#     && scripts/screenshot_report.sh /tmp/sample_runs/report/report.html /tmp/report.png
set -euo pipefail

if [[ $# -lt 1 || $# -gt 3 ]]; then
    sed -n '2,12p' "$0" >&2
    exit 2
fi
html="$1"
out="${2:-${html%.html}.png}"
size="${3:-1400x3000}"
[[ -f "$html" ]] || { echo "screenshot_report: $html: no such file" >&2; exit 2; }

browser=""
for name in chromium chromium-browser google-chrome; do
    if command -v "$name" >/dev/null 2>&1; then browser="$(command -v "$name")"; break; fi
done
[[ -n "$browser" ]] || { echo "screenshot_report: headless Chromium not found (apt-get install -y chromium)" >&2; exit 3; }

abs_html="$(cd "$(dirname "$html")" && pwd)/$(basename "$html")"
mkdir -p "$(dirname "$out")"
abs_out="$(cd "$(dirname "$out")" && pwd)/$(basename "$out")"
profile="$(mktemp -d)"
trap 'rm -rf "$profile"' EXIT

timeout 90 "$browser" --headless --no-sandbox --disable-gpu --disable-background-networking \
    --disable-component-update --no-first-run --disable-dev-shm-usage --hide-scrollbars \
    --user-data-dir="$profile" --window-size="${size/x/,}" --screenshot="$abs_out" "file://$abs_html" \
    >/dev/null 2>"$profile/stderr.log" || { cat "$profile/stderr.log" >&2; exit 1; }
[[ -s "$abs_out" ]] || { echo "screenshot_report: Chromium wrote no screenshot" >&2; cat "$profile/stderr.log" >&2; exit 1; }
echo "wrote $abs_out"
