"""The hardware bridge: Dynamixel pan-tilt driver, its servo models and a Protocol 2.0 emulator.

Modules here may import vendor SDKs (``dynamixel_sdk``, ``serial``); the core never imports this
package. Launch files reach it through the device registry of :mod:`aes_planner.devices`.

* :mod:`.protocol` -- Protocol 2.0 codec (CRC, byte stuffing, packets).
* :mod:`.dynamixel_models` -- control tables as data; the tick <-> radian map.
* :mod:`.dynamixel` -- :class:`DynamixelPanTilt` on dynamixel-sdk, bus scan.
* :mod:`.emulator` -- servo bus emulator on a pty.
"""
