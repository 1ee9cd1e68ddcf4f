"""The fleet: questions across stations, robots and overhauls (:mod:`.questions`), their trend test
(:mod:`.trend`) and the fleet page (:mod:`.page`)."""
