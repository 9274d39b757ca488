from .cli import main

# guarded: worker processes started by spawn (the fleet's local Dask cluster) import the parent's
# __main__ again, and must not run the command a second time
if __name__ == "__main__":
    raise SystemExit(main())
