"""The 3D views: one base for the viser servers (``scene``) and the one proxy that serves them
to browsers through the app (``proxy``).
"""

from webtool.viewer.proxy import client_response, proxy_socket, viewer_router
from webtool.viewer.scene import ViserScene, refuses_browsers

__all__ = ["ViserScene", "client_response", "proxy_socket", "refuses_browsers", "viewer_router"]
