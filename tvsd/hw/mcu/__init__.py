"""The MCU link: protocol spec, framing, clock sync, the asyncio link and the stepper axes.

One module per concern: ``spec`` (protocol.yaml), ``framing`` (bytes <-> frames), ``messages``
(typed MCU -> host messages), ``clock`` (MCU ticks -> host time), ``placement`` (16/32-bit stamps
-> the unwrapped tick count), ``link`` (McuLink on a serial port: wiring, life cycle, reporting;
its parts ``io_thread``, ``receiving``, ``sending`` and ``queries``; what it hands its users,
``events``) and ``steppers`` (φ and γ axes in degrees).
"""
