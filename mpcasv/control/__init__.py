"""Execution level (guidance, surge-speed reference model, yaw PID, speed loop) and tuning."""
