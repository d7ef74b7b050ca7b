"""The API docs page (``/api/docs``): FastAPI's Swagger UI, with its script pinned and locked.

FastAPI's default page loads ``swagger-ui-dist@5`` from a CDN (whatever release 5.x is that
day) and starts it with an inline script, so the page got no content security policy, on the
origin whose ``localStorage`` holds the UI's bearer token: whoever changes what the CDN serves
for that range reads the token of everybody who opens the docs (audit of 2026-12-03, F7).
Here the release is pinned, each file carries its Subresource Integrity digest (the browser
refuses other bytes), and the page has its own policy: the CDN's files, the one inline
starter script by its hash, the gateway's own API, no framing.
"""

from __future__ import annotations

import base64
import hashlib
import re

from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import HTMLResponse

SWAGGER_UI_VERSION = "5.35.0"
CDN = "https://cdn.jsdelivr.net"
SWAGGER_JS = f"{CDN}/npm/swagger-ui-dist@{SWAGGER_UI_VERSION}/swagger-ui-bundle.js"
SWAGGER_CSS = f"{CDN}/npm/swagger-ui-dist@{SWAGGER_UI_VERSION}/swagger-ui.css"
SWAGGER_JS_SRI = "sha384-gjRm0bEPMeTmMh5jT2cHccIwCUZSTd8YC+j0d0sXw0MdGEfScduGpSyF3ZSSLkX9"
SWAGGER_CSS_SRI = "sha384-WlYgdmXYOOBWL5apwjDEZwN+U3HmXSSu5R6V5aGxEcf7z+KuRNwBhoxKVN1i3D5I"
"""sha384 of the two files of the npm package swagger-ui-dist 5.35.0 (the CDN serves npm's
bytes): `npm pack swagger-ui-dist@5.35.0`, then `openssl dgst -sha384 -binary FILE | base64`."""

_INLINE = re.compile(r"<script>(.*?)</script>", re.DOTALL)


def _policy(inline_script: str) -> str:
    digest = base64.b64encode(hashlib.sha256(inline_script.encode()).digest()).decode()
    return "; ".join(
        (
            "default-src 'none'",
            f"script-src {CDN} 'sha256-{digest}'",
            f"style-src {CDN} 'unsafe-inline'",  # Swagger UI's React sets style attributes
            "img-src 'self' data:",
            "font-src 'self' data:",
            "connect-src 'self'",  # the OpenAPI document and "Try it out"
            "base-uri 'none'",
            "form-action 'self'",
            "frame-ancestors 'none'",
        )
    )


def docs_page(openapi_url: str, title: str) -> HTMLResponse:
    """Swagger UI for ``openapi_url``: pinned, integrity-checked files and a strict policy."""
    page = get_swagger_ui_html(
        openapi_url=openapi_url,
        title=title,
        swagger_js_url=SWAGGER_JS,
        swagger_css_url=SWAGGER_CSS,
        swagger_favicon_url="data:,",
    )
    html = bytes(page.body).decode()
    locked = 'integrity="{}" crossorigin="anonymous"'
    js, css = f'<script src="{SWAGGER_JS}"', f'href="{SWAGGER_CSS}"'
    html = html.replace(f"{js}>", f"{js} {locked.format(SWAGGER_JS_SRI)}>")
    html = html.replace(f"{css}>", f"{css} {locked.format(SWAGGER_CSS_SRI)}>")
    scripts = _INLINE.findall(html)
    if SWAGGER_JS_SRI not in html or SWAGGER_CSS_SRI not in html or len(scripts) != 1:
        raise RuntimeError("FastAPI's Swagger page changed shape: review backend/api/docs_page.py")
    return HTMLResponse(html, headers={"Content-Security-Policy": _policy(scripts[0])})
