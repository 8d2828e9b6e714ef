# Sourced by ./run-tests: the browser tests (report and mosaic viewer in headless
# Chromium, via Playwright) need Debian's chromium. Installed when missing and this is a
# Debian machine we may install on (root, apt-get); otherwise those tests skip, saying so.
if ! command -v chromium >/dev/null 2>&1 && ! command -v chromium-browser >/dev/null 2>&1; then
  if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null 2>&1; then
    echo "installing chromium for the browser tests (apt-get) ..." >&2
    if ! { apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium; } \
        >/dev/null 2>&1; then
      echo "warning: could not install chromium; the browser tests will be skipped" >&2
    fi
  fi
fi
