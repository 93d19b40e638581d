"""The packing VLM over an OpenAI-compatible chat-completions API.

Client: the ``endpoint`` policy (:mod:`.endpoint`) over :mod:`.transport` (stdlib HTTP with a
deadline). Server: :mod:`.server` (a small test server), :mod:`.protocol` (request validation,
response bodies), :mod:`.model_answers` (answers of a local model, vlm extra) and the
``packlab serve`` command (:mod:`.command`; also ``python -m packlab.vlm.serve``). Both sides
share :mod:`.openai_messages` (chat messages <-> OpenAI messages).
"""
