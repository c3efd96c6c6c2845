"""rwpend pure core: rig parameters, plant model, encoders (no rclpy)."""
