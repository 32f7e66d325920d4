"""The status report: what every face of lpam says about the car."""
