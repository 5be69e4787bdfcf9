"""Who may use the browsing page: a secret token, as Jupyter does it.

The page is served with a random token in its URL (``/?token=...``). A
request without it, or without the cookie the first authorised page load
sets, gets HTTP 403: the page, its files and its websocket alike (the viser
client opens its websocket without the page's query string, so the cookie
carries the token there). A request whose ``Origin`` is not the address it
was sent to (another site's page talking to this server from the user's
browser) gets 403 even with the cookie.

viser builds its HTTP handler inside its server thread and hands it to
:func:`websockets.asyncio.server.serve`; :func:`serve_guarded` wraps that
handler while the server is constructed, and refuses to serve when it could
not (a viser that no longer calls ``serve`` this way).
"""

from __future__ import annotations

import contextlib
import hashlib
import hmac
import io
import http
import http.cookies
import ipaddress
import secrets
import socket
import threading
from urllib.parse import parse_qs, urlsplit

from mwbx.errors import MwbxError

_INSTALL = threading.Lock()  # one server constructed under the wrapper at a time


class Guard:
  """The token of one page and the check every request goes through.

  Args:
    token: the secret (default: 32 random bytes, URL-safe).
  """

  def __init__(self, token: str | None = None):
    self.token = token or secrets.token_urlsafe(32)
    # The cookie's name comes from the token, so pages on several ports of
    # one host (cookies ignore ports) each find their own.
    self.cookie = "mwbx-" + hashlib.sha256(self.token.encode()).hexdigest()[:16]
    self.installed = False

  def _token_of(self, request) -> tuple[bool, bool]:
    """(authorised, by the URL's token) for a websockets Request."""
    given = parse_qs(urlsplit(request.path).query).get("token", [""])[0]
    if given and hmac.compare_digest(given.encode(), self.token.encode()):
      return True, True
    jar = http.cookies.SimpleCookie()
    try:
      jar.load(request.headers.get("Cookie", ""))
    except http.cookies.CookieError:
      return False, False
    morsel = jar.get(self.cookie)
    return morsel is not None and hmac.compare_digest(morsel.value.encode(), self.token.encode()), False

  def refusal(self, request) -> str | None:
    """Why ``request`` is refused (None: it may go on)."""
    origin = request.headers.get("Origin")
    if origin is not None:
      host = request.headers.get("Host", "").lower()
      if origin == "null" or urlsplit(origin).netloc.lower() != host:
        return "foreign Origin"
    authorised, _ = self._token_of(request)
    return None if authorised else "no valid token"

  def wrap(self, process_request):
    """viser's ``process_request`` behind the check; a page loaded with the
    URL's token also gets the cookie its websocket will carry."""

    def guarded(connection, request):
      why = self.refusal(request)
      if why is not None:
        return connection.respond(http.HTTPStatus.FORBIDDEN,
                                  f"403 Forbidden: {why}. Open the URL mwbx browse printed (with ?token=...).\n")
      response = None if process_request is None else process_request(connection, request)
      if response is not None and self._token_of(request)[1]:
        response.headers["Set-Cookie"] = f"{self.cookie}={self.token}; Path=/; HttpOnly; SameSite=Strict"
      return response

    self.installed = True
    return guarded


def serve_guarded(make_server, guard: Guard):
  """``make_server()`` (which constructs and starts a viser server) with every
  request it will serve going through ``guard``. viser's own banner (its
  address without the token, which only gets 403) is not printed.

  Raises:
    MwbxError: the wrapper was never called (viser changed how it serves):
      the server is stopped rather than left open.
  """
  import websockets.asyncio.server as ws_server
  with _INSTALL:
    original = ws_server.serve

    def serve(handler, *args, process_request=None, **kwargs):
      return original(handler, *args, process_request=guard.wrap(process_request), **kwargs)

    ws_server.serve = serve
    try:
      with contextlib.redirect_stdout(io.StringIO()):
        server = make_server()
    finally:
      ws_server.serve = original
  if not guard.installed:
    server.stop()
    raise MwbxError("browse: this viser version cannot be served behind a token; refusing to serve")
  return server


def resolve_host(host: str, flag: str = "host") -> bool:
  """Whether ``host`` is loopback only (every address it resolves to).

  Args:
    host: a name or address.
    flag: how the caller spells it, for messages (a command line: ``--host``).

  Raises:
    MwbxError: it does not resolve (one line naming it).
  """
  try:
    infos = socket.getaddrinfo(host, None, type=socket.SOCK_STREAM)
  except (socket.gaierror, UnicodeError) as err:
    reason = getattr(err, "strerror", None) or str(err)
    raise MwbxError(f"browse: {flag} {host!r}: no such address ({reason})") from None
  return all(ipaddress.ip_address(info[4][0].split("%")[0]).is_loopback for info in infos)
