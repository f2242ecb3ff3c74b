"""The devices without the hardware: pty emulators of the Superstar II, the BP3010 and a u-blox receiver
(``emulate``), the message sources they serve (``sources``; the simulator's are ``sim.messages`` and
``sim.ublox``), ``gpsins emulate`` (``cli``) and a simulated laboratory day recorded through the logger
(``lab``).
"""
