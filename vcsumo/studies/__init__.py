"""Studies: functions from a study definition to a results folder (CSV + plots)."""
