"""Latitude/longitude to UTM metres, in one common zone so that distances between any two images are right.

UTM zones are 6° wide; converting each point in its own zone would put two images a few metres apart, on either
side of a zone boundary, hundreds of kilometres apart. :func:`latlon_to_utm` therefore projects every point into
one zone (by default the zone of the median point), where distortion stays negligible at the scale of a VPR
dataset (a city, a few zones at most).
"""

from __future__ import annotations

import numpy as np

__all__ = ["latlon_to_utm"]


def _import_utm():
    try:
        import utm
    except ImportError as error:  # pragma: no cover - utm is a dependency
        raise ImportError("converting latitude/longitude to metres needs the 'utm' package: pip install utm") from error
    return utm


def latlon_to_utm(
    latitude: object,
    longitude: object,
    *,
    zone_number: int | None = None,
    northern: bool | None = None,
) -> tuple[np.ndarray, int, bool]:
    """Project WGS84 latitude/longitude to UTM easting/northing in metres, all in one zone.

    Parameters
    ----------
    latitude, longitude : array-like of shape (N,)
        Degrees; latitude in [-80, 84], longitude in [-180, 180].
    zone_number : int, optional
        UTM zone (1-60) to project into; by default the zone of the median point.
    northern : bool, optional
        Hemisphere of the projection; by default that of the median latitude. Points of the other hemisphere
        get negative (southern zone) or > 10,000 km (northern zone) northings, which keeps distances right.

    Returns
    -------
    positions : ndarray of shape (N, 2), float64
        Easting and northing in metres.
    zone_number : int
        The zone used.
    northern : bool
        The hemisphere used.

    Examples
    --------
    >>> positions, zone, northern = latlon_to_utm([40.4406, 40.4408], [-79.9959, -79.9959])
    >>> zone, northern, round(float(np.linalg.norm(positions[1] - positions[0])), 1)
    (17, True, 22.2)
    """
    utm = _import_utm()
    lat = np.asarray(latitude, dtype=np.float64).reshape(-1)
    lon = np.asarray(longitude, dtype=np.float64).reshape(-1)
    if lat.shape != lon.shape:
        raise ValueError(f"latitude and longitude must have the same length, got {lat.size} and {lon.size}")
    if not (np.isfinite(lat).all() and np.isfinite(lon).all()):
        raise ValueError("latitude and longitude must be finite numbers")
    if lat.size and not ((lat >= -80).all() and (lat <= 84).all()):
        bad = int(np.flatnonzero((lat < -80) | (lat > 84))[0])
        raise ValueError(f"latitude must lie in [-80, 84] degrees (UTM), got {lat[bad]} at row {bad}")
    if lon.size and not ((lon >= -180).all() and (lon <= 180).all()):
        bad = int(np.flatnonzero((lon < -180) | (lon > 180))[0])
        raise ValueError(f"longitude must lie in [-180, 180] degrees, got {lon[bad]} at row {bad}")
    if lat.size == 0:
        return np.empty((0, 2)), int(zone_number or 0), bool(northern if northern is not None else True)
    median_lat, median_lon = float(np.median(lat)), float(np.median(lon))
    if zone_number is None:
        zone_number = int(utm.latlon_to_zone_number(median_lat, median_lon))
    if northern is None:
        northern = median_lat >= 0
    easting, northing, _, _ = utm.from_latlon(
        lat, lon, force_zone_number=int(zone_number), force_northern=bool(northern)
    )
    positions = np.column_stack([np.asarray(easting, np.float64), np.asarray(northing, np.float64)])
    return positions, int(zone_number), bool(northern)
