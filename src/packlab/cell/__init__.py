"""The cell service: packlab as a packing module a robot cell calls (docs/cell.md).

The cell sends what its depth cameras see; the service answers which box, its rotation and the
place pose in the container frame, and how the place skill would put it down. Modules:

- ``step``: the planning step as plain functions (``open_session``, ``plan_step``), no HTTP;
- ``geometry``: calibrated depth images to packlab's top-down view (pinhole, orthographic);
- ``buffer``: the buffer's boxes from its depth image (packlab's segmentation and box fit);
- ``images``: the depth images' wire encodings;
- ``errors``, ``limits``: what a refusal carries, and the documented limits;
- ``schema``, ``convert``: the HTTP requests and answers, and their mapping to ``step``;
- ``sessions``, ``workers``: open sessions, in the server process or in planner processes;
- ``app``, ``server``, ``settings``: the FastAPI app and ``packlab cell serve``;
- ``client``: ``CellClient``, the Python client;
- ``simulated``: packlab's simulated cameras as a cell describes them, and a generated case's
  steps rendered and encoded as a cell sends them;
- ``via_cell``: the bench's episodes played through a running service (``packlab bench
  --via-cell URL``).

``step``, ``geometry``, ``buffer``, ``images``, ``errors``, ``limits`` and ``settings`` need the
core install only; the rest needs the ``cell`` extra (FastAPI, uvicorn, httpx, pydantic).
"""
