"""The operator page (``delegation ui``, ``serve --http``, ``demo --http``): docs/ui.md.

``view`` (pure) holds the live operator state built from decoded messages, ``geometry`` and
``mission_input`` (pure) turn plans and mission text into what the page draws and sends, ``bridge``
feeds the view from one MQTT connection and sends commands to the service, ``app`` is the
Starlette application, ``server`` runs it with uvicorn, ``auth`` reads the users file.
"""
