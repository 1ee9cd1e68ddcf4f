"""ISO 9283 pose characteristics: attained poses from a stream or a stop list, the characteristics,
held poses, lab files."""
