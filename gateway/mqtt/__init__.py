"""Publishing every poll to an MQTT broker: frame payloads (``payload``), the publisher that
runs beside the poll loop (``publisher``) and its Prometheus counters (``collector``).
Receiving them, ``tactile-gateway subscribe``: the paho client loop (``subscriber``), the
broker and topics (``subscribe_settings``), messages into frames with their sequence
bookkeeping (``frame_stream``) and a frame's record rows (``frame_rows``).
``docs/mqtt.md`` documents topics and payloads."""
