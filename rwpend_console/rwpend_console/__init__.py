"""The lab console: the rig in a web browser (live plots, mode, tap, record, gains, e-stop, the
diagnostics as lights, the bags and their plots, every rig of the lab) and the Foxglove
WebSocket bridge.

Pure modules (no rclpy, tested without ROS): :mod:`.decimate`, :mod:`.access`, :mod:`.panel`,
:mod:`.lights`, :mod:`.feed`, :mod:`.rigs`, :mod:`.bags`, :mod:`.foxglove_params`,
:mod:`.schemas`. The rclpy side: :mod:`.rosside` (the console's node), :mod:`.bridge` (the
bridge); the web server: :mod:`.web`; the command: :mod:`.console`.
"""
