"""The hardware bridge: Dynamixel pan-tilt driver, its servo models and a Protocol 2.0 emulator.

Modules here may import vendor SDKs (``dynamixel_sdk``, ``serial``); the core never imports this
package. Launch files reach it through the device registry of :mod:`aes_planner.devices`.

* :mod:`.protocol` -- Protocol 2.0 codec (CRC, byte stuffing, packets).
* :mod:`.dynamixel_models` -- servo facts as data: control tables, model numbers, operating
  modes, baud tables, hardware-error bits; the tick <-> radian map.
* :mod:`.dynamixel_config` -- the settings dataclasses (no SDK import).
* :mod:`.dynamixel` -- :class:`DynamixelPanTilt` on dynamixel-sdk, bus scan.
* :mod:`.emulator` -- servo bus emulator on a pty.
* :mod:`.emulated` -- :class:`EmulatedPanTilt`: the driver on a built-in emulator.
* :mod:`.sim_gimbal` -- :class:`SimPanTilt`: a light in-process simulation (no port, no SDK).
"""
