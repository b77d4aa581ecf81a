"""The camera mount page: where the camera sits on the drone.

``routes`` (the JSON API), ``service`` (the mount being set and saved), ``scene`` (the 3D view).
"""

from webtool.mount.service import MountService, mount_in_use

__all__ = ["MountService", "mount_in_use"]
