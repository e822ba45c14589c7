"""Message types: classes for any type (installed or built from stored definitions), a
message's decoded fields, and how much of each message the recorder decodes (no ROS)."""
