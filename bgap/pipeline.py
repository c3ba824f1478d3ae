from bgap.runner.numerics import command

main = command("bgap.experiments.pipeline")
if __name__ == "__main__":
    main()
