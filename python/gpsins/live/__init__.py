"""Live navigation beside the logger (``gpsins live``): ``service`` runs it, ``follower`` follows the
growing session and feeds the streaming filter, ``outputs`` holds what it writes (NMEA, the epochs file),
``page`` the status page.
"""
