"""The ground station: every drone on the site's Zenoh network in one place.

:class:`Fleet` holds what is known of each drone; :class:`StationLink` fills it from Zenoh
(the drones' ``--sink zenoh:`` publications and liveliness tokens).
"""

from drovisio.station.fleet import LOST_AFTER_S, DroneStatus, Fleet
from drovisio.station.link import StationLink, liveliness_key

__all__ = ["LOST_AFTER_S", "DroneStatus", "Fleet", "StationLink", "liveliness_key"]
