from stillcap.cli import main

if __name__ == "__main__":  # not again in a spawned process (Dask, multiprocessing) that imports it
    main()
