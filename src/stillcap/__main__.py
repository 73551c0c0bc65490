from stillcap._entry import run

if __name__ == "__main__":  # not again in a spawned process (Dask, multiprocessing) that imports it
    run()
