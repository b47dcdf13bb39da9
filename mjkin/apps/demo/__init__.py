"""The demo scenes: the seeds' arm, the 7-DoF arm among obstacles, the walk."""
