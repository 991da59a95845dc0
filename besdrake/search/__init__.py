"""Policy search: ask/tell optimizers, contextual policy search, behaviour templates."""
