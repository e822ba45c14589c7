"""People traffic: sparse variational GP regression of people counts over space and time of day."""
