"""Readers of the files the station takes in: bounded, explicit about encoding, and every
failure a :class:`~station.errors.DataError` naming the file, the line and the column."""
