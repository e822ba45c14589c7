"""Storage: one store interface (`storage.store.open_store`) over the CouchDB and MongoDB
backends, the stored document form, the one CouchDB HTTP client and the Mango selector evaluator."""
