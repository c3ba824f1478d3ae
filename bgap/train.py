from bgap.runner.numerics import command

main = command("bgap.experiments.train")
if __name__ == "__main__":
    main()
