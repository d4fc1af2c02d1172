"""rescue-hq's browser console: a local web page with the map, the victims and the actions.

state (what a page shows, as JSON), notes (operator notes in the registry file),
access (who may use it), assets (Leaflet, vendored at set-up), feed (the thread
that watches the registry and builds the page state), downloads (exports, CSV),
server (Starlette on uvicorn, in rescue-hq's process). See docs/HQ.md, "The console".
Reads and writes the registry through hq's own modules; never imports the companion.
"""
