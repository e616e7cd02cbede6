#!/bin/sh
# Render the quickstart's HTML report with headless Chromium into docs/figures/quickstart_report.png
# (the screenshot README.md shows). Runs the quickstart (studies/quickstart.toml, about a minute on
# two cores) into a scratch folder, writes its report with `uqflow report --html`, and screenshots
# the top of the page. Needs the Debian package chromium (apt-get install chromium).
#   usage: tools/report_screenshot.sh [WIDTHxHEIGHT]     (default 1280x2000)
set -eu
root=$(cd "$(dirname "$0")/.." && pwd)
size=${1:-1280x2000}
browser=$(command -v chromium || command -v chromium-browser || true)
if [ -z "$browser" ]; then
    echo "report_screenshot.sh: chromium not found: install the Debian package 'chromium'" >&2
    exit 2
fi
if ! command -v uqflow > /dev/null; then
    echo "report_screenshot.sh: uqflow not found: activate the environment it is installed in" >&2
    exit 2
fi
scratch=$(mktemp -d)
trap 'rm -rf "$scratch"' EXIT
cd "$root"
uqflow run studies/quickstart.toml --output "$scratch/quickstart.nc" --quiet --no-figures \
    > "$scratch/run.log"
uqflow report "$scratch/quickstart.nc" --html --figures "$scratch/figures" > "$scratch/report.log"
mkdir -p docs/figures
# --no-sandbox: Chromium refuses to run as root with its sandbox; the page is our own file.
"$browser" --headless --no-sandbox --disable-gpu --hide-scrollbars \
    --window-size="$(echo "$size" | tr x ,)" \
    --screenshot="$root/docs/figures/quickstart_report.png" \
    "file://$scratch/figures/quickstart_report.html" 2> "$scratch/chromium.log" || {
        echo "report_screenshot.sh: chromium failed (its log: $(tail -n 1 "$scratch/chromium.log"))" >&2
        exit 1; }
echo "docs/figures/quickstart_report.png"
