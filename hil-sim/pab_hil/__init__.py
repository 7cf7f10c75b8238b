"""pab-hil: hardware-in-the-loop for pab nodes on a SocketCAN bus.

The layout follows one closed loop:

- `world`: the Take and Return world (arm, hand, gaze, object, person), moved only by what the
  nodes deliver; `person`: the person's script, reacting to the robot.
- `behaviours`: the seven publishers of Figure 4, each a forked process with its own socket.
- `nodes`: the `pab-node` processes and `pabctl` (push, compile); `transfer`: pushes through a
  third-party ISO-TP stack (python can-isotp), for corrupted images and interop.
- `observe`: the candump recorder process and the harness's listening socket; `protocol`: the
  node frames it decodes; `phases`: A to F as the world shows them.
- `scenario`: a session wiring all of the above; `plot`, `analysis`: figures from the log.
- `vm`: the QEMU micro-VM with a vcan0, for kernels without SocketCAN.

Nothing here arbitrates: the nodes do, with the project's own code.
"""
