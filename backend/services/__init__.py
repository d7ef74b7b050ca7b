"""Gateway services: the chain connection and signing (:mod:`.chain`), the embedded JSON-RPC
endpoint (:mod:`.rpc`) and the off-chain documents (task specs, model bundles; :mod:`.specs`)."""
