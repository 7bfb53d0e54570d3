"""The localizer: `localizer.localize` (the entry point: graph pair -> LocalizationResult),
its settings (`config.LocalizerConfig`, named `presets`), maps prepared once for many queries
(`prepared.PreparedMap`) and the correspondence-only entry `registration.register`."""
