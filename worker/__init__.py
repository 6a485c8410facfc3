"""Job execution: worker processes that claim jobs and run the engine. Imports api + engine."""
